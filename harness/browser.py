"""Headless Chromium for the browser tests and benchmarks: Debian's chromium driven by Playwright (never
``playwright install``), WebGL2 through SwiftShader where the machine has no GPU (``--use-angle=swiftshader
--enable-unsafe-swiftshader``: Chrome no longer falls back to it by itself), and the browser renderer's modules
(app/static/render) driven straight from Python."""
from __future__ import annotations

import base64
import contextlib
import functools
import http.server
import os
import shutil
import tempfile
import threading
from pathlib import Path
from typing import Any, Iterator

import cv2
import numpy as np

from workers.camera import Camera

STATIC = Path(__file__).resolve().parents[1] / "app" / "static"
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
BASE_ARGS = ["--no-sandbox", "--disable-quic", "--no-first-run", "--disable-background-networking",
             "--disable-component-update", "--disable-sync"]
SWIFTSHADER_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]
GPU_ARGS = ["--use-angle=vulkan", "--enable-features=Vulkan", "--ignore-gpu-blocklist"]


def have_chromium() -> bool:
    return Path(CHROMIUM).exists()


@contextlib.contextmanager
def chromium(webgl: str = "swiftshader") -> Iterator[Any]:
    """A headless Chromium (Playwright Browser); webgl: "swiftshader" (software WebGL2, any machine), "gpu" (the
    machine's GPU through ANGLE/Vulkan) or "none" (no WebGL, as ``--disable-gpu``). Profile in a temp dir."""
    from playwright.sync_api import sync_playwright

    args = BASE_ARGS + {"swiftshader": SWIFTSHADER_ARGS, "gpu": GPU_ARGS, "none": ["--disable-gpu"]}[webgl]
    with tempfile.TemporaryDirectory(prefix="sweepcast-chromium-") as home:
        env = {**os.environ, "XDG_CONFIG_HOME": f"{home}/config", "XDG_CACHE_HOME": f"{home}/cache"}
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=["--headless=new", *args],
                                         env=env)
            try:
                yield browser
            finally:
                browser.close()


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args: Any) -> None:  # the tests' output is not an access log
        pass


@contextlib.contextmanager
def static_site(root: Path = STATIC) -> Iterator[str]:
    """``root`` served over HTTP on a free loopback port (ES modules need an http origin): its base URL."""
    handler = functools.partial(_Quiet, directory=str(root))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


def png_b64(image: np.ndarray) -> str:
    return base64.b64encode(cv2.imencode(".png", image)[1].tobytes()).decode()


_RENDER = """async ({spec, atlas, background, camera, factor, options, overlay, repeat, sgmBlock, later, hold}) => {
  const { BrowserRenderer } = await import("/render/renderer.js");
  const { Camera } = await import("/render/camera.js");
  const { capabilities } = await import("/render/gl.js");
  const canvas = document.createElement("canvas");
  canvas.width = camera.width;
  canvas.height = camera.height;
  document.body.append(canvas);
  const caps = capabilities(canvas);
  if (!caps.ok) throw new Error(caps.reason);
  const gl = caps.gl;
  const bitmap = async (b64) => createImageBitmap(await (await fetch(`data:image/png;base64,${b64}`)).blob(),
    { premultiplyAlpha: "none", colorSpaceConversion: "none" });
  const r = await BrowserRenderer.create(gl, spec);
  if (sgmBlock) r.semiGlobal.block = sgmBlock;
  r.useFactor(factor);
  if (background) r.frames.setBackgrounds(await bitmap(background), spec.atlas_columns);
  r.frames.setFrames(await bitmap(atlas), spec.atlas_columns);
  const view = new Camera("virtual", camera.K.flat(), camera.R.flat(), camera.t, camera.width, camera.height);
  let info;
  const times = [];
  for (let i = 0; i < repeat; i++) {
    const t0 = performance.now();
    info = r.render(view, options);
    r.present(overlay);
    r.finish();
    times.push(performance.now() - t0);
  }
  const b64 = (array) => { let s = ""; const u = new Uint8Array(array.buffer);
    for (let i = 0; i < u.length; i += 8192) s += String.fromCharCode(...u.subarray(i, i + 8192)); return btoa(s); };
  const images = [];
  for (const next of later) {  // newer frame sets of the same view
    images.push(b64(r.readImage()));
    r.frames.setFrames(await bitmap(next), spec.atlas_columns);
    info = r.render(view, options, { hold });
    r.present(overlay);
  }
  const out = { info, times, gpu: caps.gpu, image: b64(r.readImage()), depth: b64(r.readDepth()), images };
  r.dispose();
  canvas.remove();
  return out;
}"""


def render_in_browser(page: Any, spec: dict, atlas: np.ndarray, background: np.ndarray | None, camera: Camera,
                      factor: int, options: dict, overlay: str = "none", repeat: int = 1,
                      sgm_block: int | None = None, later: tuple[np.ndarray, ...] = (), hold: bool = True) -> dict:
    """Render ``camera``'s view with the browser renderer in ``page`` (on a page of a site serving app/static):
    spec from :func:`workers.streaming.browser.render_spec`, frame and background atlases (BGR) from
    :func:`workers.streaming.browser.frame_atlas` at ``factor``. Returns the renderer's info, ``times`` (ms per
    render until the GPU has drawn it, ``repeat`` of them), ``gpu`` (the WebGL renderer string), ``image``
    (h, w, 3) uint8 BGR as presented and ``depth`` (h, w, 4) float32 (inverse depth or 0, plane or -1, sub-plane
    offset, cost). sgm_block: the lines a semi-global draw advances (the renderer's choice for its GPU if None).
    later: atlases of newer frame sets, uploaded in turn after the timed renders and the same view drawn on each,
    with ``hold`` its depth kept where the scene stood still; what is returned is then the last one's, and
    ``images`` those presented before it (the first set's, then each later one's but the last)."""
    out = page.evaluate(_RENDER, {
        "spec": spec, "atlas": png_b64(atlas), "background": None if background is None else png_b64(background),
        "camera": {"K": camera.K.tolist(), "R": camera.R.tolist(), "t": camera.t.tolist(), "width": camera.width,
                   "height": camera.height},
        "factor": factor, "options": options, "overlay": overlay, "repeat": repeat, "sgmBlock": sgm_block,
        "later": [png_b64(a) for a in later], "hold": hold,
    })
    h, w = camera.height, camera.width
    rgba = np.frombuffer(base64.b64decode(out["image"]), np.uint8).reshape(h, w, 4)
    depth = np.frombuffer(base64.b64decode(out["depth"]), np.float32).reshape(h, w, 4)
    earlier = [np.frombuffer(base64.b64decode(b), np.uint8).reshape(h, w, 4)[:, :, 2::-1] for b in out["images"]]
    return {**out, "image": np.ascontiguousarray(rgba[:, :, 2::-1]), "depth": depth,
            "images": [np.ascontiguousarray(e) for e in earlier]}
