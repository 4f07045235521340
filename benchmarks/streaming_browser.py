"""The virtual view rendered in the viewer's browser (app/static/render, WebGL2) against the server's renderer.

``python -m benchmarks.streaming_browser --only PART[,PART] [...]`` (``--list``; without ``--only`` every part runs);
each part writes its own section of RESULTS.md:

- ``quality``: views held out of real and synthetic rigs (Middlebury Teddy view 4 and Art view 3, from two and from
  all other views; the demo studio seen from between its cameras, against the ray-cast truth), rendered by the
  server's renderer and by the browser's with the same options (the old defaults: window aggregation at full
  resolution, the server's, and coarse-to-fine, the viewer's; the viewer's quality levels, fast and best:
  workers/streaming/quality.py), the browser fed lossless frames and the JPEG frame sets the service ships: PSNR
  against the held-out view on the pixels both renderers found a surface for. Goal: the browser within 0.3 dB of
  the server. Section ``streaming_browser_quality``.
- ``fps``: browser render time at 320x240, 640x480 and 1280x720 with 48 and 64 planes from the demo rig's 10
  cameras (640x480 frames), as the viewer renders (coarse-to-fine) and at full resolution, with window and with
  semi-global aggregation, and the viewer's with semi-global aggregation and the occlusion fill (full-resolution
  sgm only up to 640x480 x 64 planes on SwiftShader; what exceeds the browser's memory limit is listed as refused),
  as frames per second and as samples per second (view pixels x planes x cameras per second, and pixels x planes:
  the "disparity evaluations" of Yang & Pollefeys' GPU plane sweep); the server's renderer on the same view in the
  same run. ``--webgl swiftshader`` (default, any machine: a CPU floor) or ``gpu`` (Chromium on the machine's
  GPU). Section ``streaming_browser_fps`` (``_gpu`` suffix for the GPU).
- ``cost``: what browser-rendering viewers cost the server, on a served app with the demo rig: 1, 8 and 32 viewers
  of the demo recording (each loads every frame set once, as the browser's cache then holds them, then watches)
  and of the live stream (frame sets of 10 640x480 JPEG cameras pushed at 5 sets/s); server CPU (its process tree)
  and bytes per viewer, while loading and in steady state; anchors in the same run: one server-rendered viewer of
  the recording (closed loop, 640x480) and the live ingest with no viewer. The recording's viewers are headless
  Chromium pages (``--chromium N``) and protocol clients doing what the page does (HTTP frame sets + socket).
  Section ``streaming_browser_cost``.
- ``latency``: time from a pointer move to the new frame on screen in the viewer page, browser mode against server
  mode, the same drags in the same page (SwiftShader here). Section ``streaming_browser_latency``.
- ``flicker``: the demo recording (the ball circling) through a fixed view at two azimuths, each frame set drawn
  by the server's renderer and by the browser's at the viewer's quality levels, the depth searched anew and held
  where the scene stood still (the server's ``previous``, the browser's ``hold``): the mean absolute change between
  consecutive frames on the pixels whose true colour stayed the same, and the browser's frames against the server's.
  Section ``streaming_browser_flicker``.
- ``first_frame``: the viewer page opened as a new user opens it (Render auto, Quality auto) in a browser without a
  GPU: plain headless Chromium (``--disable-gpu``; Debian's Chromium still offers WebGL2 there, on SwiftShader) and
  with SwiftShader asked for (a CPU rasteriser, which the page now sends to the server at once), and
  ``?render=server`` for reference; ms from the page's navigation to its first view drawn, the mode it chose and
  the quality shown. Goal: <= 1 s. Section ``streaming_browser_first_frame``.
"""
from __future__ import annotations

import asyncio
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import httpx
import numpy as np
import websockets

from benchmarks._report import Sections, md_table
from benchmarks._timing import settle_server
from benchmarks.sweep.common import still_between
from harness.browser import chromium, render_in_browser, static_site
from workers.common.datasets import dataset
from workers.common.imagemetrics import psnr
from workers.streaming.browser import encode_atlas, frame_atlas, render_spec
from workers.streaming.demo import demo_rig, demo_scene
from workers.streaming.params import Orbit
from workers.streaming.quality import LEVELS
from workers.streaming.session import shrunk_images, shrunk_rig, source_factor
from workers.streaming.viewpoint import orbit_camera, orbit_frame
from workers.sweep.renderer import RenderOptions, SweepRenderer
from workers.sweep.rig import Rig
from workers.sweep.rig_io import rectified_rig, rig_from_dict
from workers.synth import render_views

GOAL_DB = 0.3
REF_SPACINGS = 4
CONFIGS = {"old server default (window)": {}, "old viewer default (window, coarse-to-fine)": {"coarse_to_fine": True},
           **{f"{level} ({'semi-global' if level == 'fast' else 'semi-global + occlusion fill'})":
              {"coarse_to_fine": True, **LEVELS[level]} for level in ("fast", "best")}}
WINDOW_CONFIGS = ["old server default (window)", "old viewer default (window, coarse-to-fine)"]
STUDIO_AZIMUTHS = (-33.0, -13.0, 18.0)  # between the demo rig's cameras (10 degrees apart, at -45 .. 45)
FIRST_FRAME_GOAL_MS = 1000.0
MIDDLEBURY = {  # folder, file prefix, held-out view, GT disparity file and its divisor, source sets
    "teddy": ("teddy", "im", 4, "disp2.pgm", 4.0, {"two": [2, 6], "all": [0, 1, 2, 3, 5, 6, 7, 8]}),
    "art": ("art", "view", 3, "disp1.png", 2.0, {"two": [1, 5], "all": [0, 1, 2, 4, 5, 6]}),
}
JPEG = {"jpeg q90": [cv2.IMWRITE_JPEG_QUALITY, 90],
        "jpeg q95 4:4:4": [cv2.IMWRITE_JPEG_QUALITY, 95, cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
                           cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444]}


# --- quality ----------------------------------------------------------------------------------------
def memory_refusal(exc: Exception) -> str | None:
    """The renderer's refusal of cost volumes beyond its memory limit, shortened ("needs 618 MB of GPU memory"),
    or None for any other error."""
    text = str(exc)
    if "MB of GPU memory" not in text:
        return None
    return "needs " + text.split(" needs ", 1)[1].split(" (", 1)[0]


def through_jpeg(atlas: np.ndarray, params: list[int]) -> tuple[np.ndarray, int]:
    """The atlas as a browser gets it in JPEG (decoded here, as libjpeg-turbo decodes it there) and its size."""
    data = cv2.imencode(".jpg", atlas, params)[1]
    return cv2.imdecode(data, cv2.IMREAD_COLOR), int(data.size)


def middlebury_cases(quick: bool) -> list[dict]:
    cases = []
    for name, (sub, prefix, target, disp_file, div, sets) in MIDDLEBURY.items():
        folder = dataset("multiview", sub)
        if folder is None:
            print(f"skipping {name}: not in $SWEEPCAST_DATA")
            continue
        images = {int(p.stem[len(prefix):]): cv2.imread(str(p)) for p in folder.glob(f"{prefix}*.png")
                  if p.stem[len(prefix):].isdigit()}
        h, w = images[target].shape[:2]
        # per view spacing (the rig's unit baseline): the GT disparities span 4 spacings (benchmarks/sweep/stereo.py)
        disp = cv2.imread(str(folder / disp_file), cv2.IMREAD_UNCHANGED).astype(np.float64) / div / REF_SPACINGS
        lo, hi = np.percentile(disp[disp > 0], [0.5, 99.5])
        for set_name, sources in sets.items():
            views = sorted([*sources, target])
            full = rectified_rig([f"{prefix}{k}.png" for k in views], w, h, positions=views)
            rig = Rig(tuple(c for c, k in zip(full.cameras, views) if k != target))
            virtual = full.cameras[views.index(target)]
            truth = images[target]
            if quick:
                virtual = virtual.scaled(0.5)
                truth = cv2.resize(truth, (virtual.width, virtual.height), interpolation=cv2.INTER_AREA)
            cases.append({"name": f"{name} view {target} from {set_name} ({len(sources)})", "rig": rig,
                          "frames": [images[k] for k in sources], "backgrounds": None, "virtual": virtual,
                          "truth": truth, "options": {"near": w / (hi * 1.1), "far": w / (lo * 0.9), "planes": 64}})
    return cases


def demo_cases(quick: bool) -> list[dict]:
    size = (320, 240) if quick else (640, 480)
    rig = demo_rig(10, size)
    scene = demo_scene(0.25)
    views = render_views(scene, list(rig.cameras))
    cases = []
    for azimuth in STUDIO_AZIMUTHS:
        virtual = orbit_camera(orbit_frame(rig), Orbit(azimuth=azimuth), 50.0, size)
        truth = render_views(scene, [virtual], with_background=False)[0].image
        cases.append({"name": f"demo studio at azimuth {azimuth:g}", "rig": rig, "frames": [v.image for v in views],
                      "backgrounds": [v.background for v in views], "virtual": virtual, "truth": truth,
                      "options": {"planes": 48}})
    return cases


def quality(quick: bool) -> tuple[dict, str]:
    cases = middlebury_cases(quick) + demo_cases(quick)
    rows, results, refused = [], [], []
    with static_site() as base, chromium() as browser:
        page = browser.new_page()
        page.goto(f"{base}/render/renderer.js")
        for case in cases:
            rig, virtual = case["rig"], case["virtual"]
            factor = source_factor(rig, virtual.width, virtual.height)
            small = shrunk_rig(rig, factor)
            frames = shrunk_images(case["frames"], small)
            bgs = None if case["backgrounds"] is None else shrunk_images(case["backgrounds"], small)
            server = SweepRenderer(small, frames, backgrounds=bgs, device="cpu")
            atlas = frame_atlas(case["frames"], rig, factor)
            bg_atlas = None if case["backgrounds"] is None else frame_atlas(case["backgrounds"], rig, factor)
            spec = render_spec(rig)
            for config, extra in CONFIGS.items():
                options = {**case["options"], **extra}
                ref = server.render(virtual, RenderOptions(**options))
                feeds = {"png (default)": (atlas, bg_atlas, len(cv2.imencode(".png", atlas)[1]))}
                for label, params in JPEG.items():
                    jpeg_atlas, nbytes = through_jpeg(atlas, params)
                    jpeg_bg = None if bg_atlas is None else through_jpeg(bg_atlas, params)[0]
                    feeds[label] = (jpeg_atlas, jpeg_bg, nbytes)
                try:
                    outs = {label: render_in_browser(page, spec, a, b, virtual, factor, options)
                            for label, (a, b, _) in feeds.items()}
                except Exception as exc:  # noqa: BLE001 - only the renderer's refusal of volumes beyond its memory
                    why = memory_refusal(exc)
                    if why is None:
                        raise
                    refused.append(f"{case['name']}, {config} at {virtual.width}x{virtual.height}: {why}")
                    print(refused[-1], flush=True)
                    continue
                mask = np.isfinite(ref.depth) & np.logical_and.reduce([o["depth"][:, :, 0] > 0 for o in outs.values()])
                server_db = psnr(ref.image, case["truth"], mask)
                lossless = outs["png (default)"]["image"]
                apart = np.abs(lossless.astype(np.int16) - ref.image.astype(np.int16)).max(axis=2) > 8
                row = {"case": case["name"], "config": config, "server_db": server_db, "coverage": float(mask.mean()),
                       "browser_vs_server_db": psnr(lossless, ref.image), "apart_px": int(apart.sum()),
                       "browser": {label: {"db": psnr(o["image"], case["truth"], mask), "bytes": feeds[label][2],
                                           "same_plane": float(np.mean(o["depth"][:, :, 1].astype(int) == ref.plane_index))}
                                   for label, o in outs.items()}}
                results.append(row)
                print(json.dumps({k: v for k, v in row.items()}, default=float))
                rows.append([row["case"], config, f"{virtual.width}x{virtual.height}", row["coverage"], server_db,
                             *[row["browser"][k]["db"] - server_db for k in feeds], row["browser_vs_server_db"],
                             f'{row["browser"]["png (default)"]["same_plane"]:.3%}', row["apart_px"],
                             *[row["browser"][k]["bytes"] for k in feeds]])
    labels = ["png (default)", *JPEG]

    def worst(configs):
        return {k: min(r["browser"][k]["db"] - r["server_db"] for r in results if r["config"] in configs) for k in labels}

    md = [md_table(["view", "options", "size", "scored", "server dB", *[f"browser - server dB, {k}" for k in labels],
                    "browser vs server picture dB (png)", "same plane (png)", "pixels > 8 levels apart (png)",
                    *[f"bytes per frame set, {k}" for k in labels]], rows), ""]
    for name, configs in (("the old defaults (window)", WINDOW_CONFIGS),
                          ("the quality levels (fast, best)", [c for c in CONFIGS if c not in WINDOW_CONFIGS])):
        w = worst(configs)
        md.append(f"Goal: the browser within {GOAL_DB} dB of the server on the same pixels. Worst difference over the "
                  f"views, {name}: " + "; ".join(f"{k} {w[k]:+.2f} dB ({'met' if w[k] >= -GOAL_DB else 'missed'})"
                                                 for k in labels) + ".")
    if refused:
        md.append("\nLeft to the server by the browser (its cost volumes would exceed the browser's memory limit): "
                  + "; ".join(refused) + ".")
    md.append("\nPSNR against the held-out view on the pixels both renderers found a surface for. The browser renders "
              "in headless Chromium through SwiftShader (the same shaders a GPU runs). The service ships lossless PNG "
              "frame sets by default (`viewer_frame_format`); the JPEG columns are the frame sets encoded as "
              "`viewer_frame_format=jpeg` (quality 90, 4:2:0) or at quality 95 without chroma subsampling would ship "
              "them, decoded by libjpeg-turbo (OpenCV here; Chromium uses the same library); the server's renderer "
              "always has the lossless frames. Bytes: one frame set (every camera) at the view's source factor.")
    studio = [r for r in results if r["case"].startswith("demo")]
    real = [r for r in results if not r["case"].startswith("demo")]
    if studio and real:
        md.append(
            "\nThe browser vs server picture: PSNR between the two renders of the same view (all pixels), and how many "
            "pixels differ by more than 8 levels in a channel. On the real views at most "
            f"{max(r['apart_px'] for r in real)} pixels differ. On the synthetic studio "
            f"{min(r['apart_px'] for r in studio)}-{max(r['apart_px'] for r in studio)} do: its surfaces have no "
            "texture, so many planes tie exactly, and a float32 sum that differs in its last bit flips the tie (a "
            "semi-global path then carries the flipped choice along its scanline). With semi-global aggregation the "
            f"studio's views score {min(r['server_db'] for r in studio if 'semi' in r['config']):.0f}-"
            f"{max(r['server_db'] for r in studio if 'semi' in r['config']):.0f} dB against the truth with the levels.")
    return {"cases": results, "worst_db": worst(list(CONFIGS)), "quick": quick}, "\n".join(md)


# --- frame rate -------------------------------------------------------------------------------------
FPS_SIZES = ((320, 240), (640, 480), (1280, 720))
FPS_PLANES = (48, 64)
FPS_CONFIGS = {"viewer (coarse-to-fine)": {"coarse_to_fine": True}, "full resolution (window)": {},
               "fast: viewer + semi-global": {"coarse_to_fine": True, **LEVELS["fast"]},
               "full resolution (sgm)": {"aggregation": "sgm"},
               "best: viewer + semi-global + occlusion fill": {"coarse_to_fine": True, **LEVELS["best"]}}
# SwiftShader keeps the semi-global volumes (5 x pixels x planes x 4 bytes) in this machine's memory and runs
# their paths on 2 cores: beyond this many pixels x planes a full-resolution sgm frame takes minutes
SWIFTSHADER_SGM_MAX = 640 * 480 * 64


def fps(quick: bool, webgl: str) -> tuple[dict, str]:
    rig = demo_rig(10, (640, 480))
    views = render_views(demo_scene(0.25), list(rig.cameras))
    frames, backgrounds = [v.image for v in views], [v.background for v in views]
    spec = render_spec(rig)
    rows, results, wire = [], [], []
    gpu = None
    with static_site() as base, chromium(webgl) as browser:
        page = browser.new_page()
        page.goto(f"{base}/render/renderer.js")
        for (w, h) in FPS_SIZES:
            factor = source_factor(rig, w, h)
            small = shrunk_rig(rig, factor)
            server = SweepRenderer(small, shrunk_images(frames, small), backgrounds=shrunk_images(backgrounds, small),
                                   device="cpu")
            atlas, bg_atlas = frame_atlas(frames, rig, factor), frame_atlas(backgrounds, rig, factor)
            wire.append([f"{w}x{h}", factor, f"{atlas.shape[1]}x{atlas.shape[0]}",
                         len(encode_atlas(atlas, "png", 0)) / 1e6, len(encode_atlas(atlas, "jpeg", 90)) / 1e6])
            camera = orbit_camera(orbit_frame(rig), Orbit(azimuth=10.0), 50.0, (w, h))
            for planes in FPS_PLANES:
                for config, extra in FPS_CONFIGS.items():
                    options = {"planes": planes, **extra}
                    # the level semi-global runs at: the half-size one with coarse-to-fine, but the fine level
                    # too with the fill (its check needs the fine level's cost volume, as on the server)
                    halved = extra.get("coarse_to_fine") and extra.get("occlusions") != "fill"
                    cells = w * h * planes / (4 if halved else 1)
                    if extra.get("aggregation") == "sgm" and webgl == "swiftshader" and cells > SWIFTSHADER_SGM_MAX:
                        continue
                    slow = w * h * planes > 640 * 480 * 48 and webgl == "swiftshader"
                    repeat = 1 if (slow or quick) else 3
                    try:
                        out = render_in_browser(page, spec, atlas, bg_atlas, camera, factor, options, repeat=repeat + 1)
                    except Exception as exc:  # noqa: BLE001 - only the renderer's refusal of volumes beyond its memory
                        why = memory_refusal(exc)
                        if why is None:
                            raise
                        rows.append([f"{w}x{h}", planes, config, f"refused: {why}", "", "", "", "", ""])
                        continue
                    gpu = out["gpu"]
                    ms = statistics.median(out["times"][1:])  # the first render compiles the shaders
                    server.render(camera, RenderOptions(**options))
                    server_ms = statistics.median(
                        [server.render(camera, RenderOptions(**options)).timings["total_ms"] for _ in range(3)])
                    samples = w * h * planes * len(rig)
                    row = {"size": f"{w}x{h}", "planes": planes, "config": config, "browser_ms": ms,
                           "browser_fps": 1000 / ms, "samples_per_s": samples / ms * 1e3,
                           "mde_per_s": w * h * planes / ms * 1e3, "server_ms": server_ms, "source_factor": factor}
                    results.append(row)
                    print(json.dumps(row), flush=True)
                    rows.append([row["size"], planes, config, ms, row["browser_fps"], row["samples_per_s"] / 1e6,
                                 row["mde_per_s"] / 1e6, server_ms, 1000 / server_ms])
    goal = [r for r in results if r["size"] == "1280x720" and r["planes"] == 64]
    md = [f"WebGL: {gpu} ({webgl}). Load average before the run: {os.getloadavg()[0]:.1f}.", "",
          md_table(["view", "planes", "options", "browser ms", "browser fps", "M samples/s (px x planes x cameras)",
                    "M disparity evaluations/s (px x planes)", "server ms (2 cores)", "server fps"], rows), "",
          "10 cameras, 640x480 frames (the demo rig; a 320x240 view sweeps them shrunk by 2, as the server does). "
          "Browser: render, present and a one-pixel readback that waits for the GPU, median of the renders after "
          "the first (which compiles the shaders). Server: `SweepRenderer.render` in this process, same view, same "
          "options, median of 3. Samples per second count the view's pixels x planes (x cameras) over the time, "
          "whatever the search skipped (coarse-to-fine tests a few planes per pixel at full resolution).", "",
          "Bytes of one frame set on the wire (every camera's frame in one atlas, as the service ships it for a view "
          "of that size):", "",
          md_table(["view", "source factor", "atlas", "MB, PNG (default)", "MB, JPEG q90"], wire)]
    if goal:
        best = max(goal, key=lambda r: r["browser_fps"])
        md.append(f"\nGoal on a GPU: 1280x720, 64 planes, 10 cameras >= 60 fps; here {best['browser_fps']:.2f} fps "
                  f"({best['config']}) on {webgl}"
                  + (": a CPU floor, not the GPU figure (no GPU machine was lent to this run)." if webgl == "swiftshader"
                     else "."))
    return {"webgl": webgl, "gpu": gpu, "rows": results, "wire": wire}, "\n".join(md)


def settle(base: str, pid: int) -> dict:
    """Wait until the served app's start-up work is done (:func:`benchmarks._timing.settle_server`: its process
    tree under 0.1 CPU seconds over two seconds, at most 10 minutes)."""
    from harness.proc import tree_cpu_seconds

    return settle_server(base, pid, tree_cpu_seconds, interval_s=2.0, timeout_s=600.0)


# --- server cost -------------------------------------------------------------------------------------
COST_VIEWERS = (1, 8, 32)
LIVE_RATE = 5.0  # frame sets per second pushed in the live phase


async def recording_viewer(base: str, rig_id: str, recording: str, factor: int, stop: asyncio.Event,
                           loaded: asyncio.Queue) -> dict:
    """What the viewer page does in browser mode, without drawing: open the socket, load the background and every
    frame set once (then the browser's cache holds them), stay connected until ``stop``."""
    ws_url = f"{base.replace('http', 'ws')}/v1/rigs/{rig_id}/view?source={recording}&render=browser"
    async with websockets.connect(ws_url, max_size=None) as ws, httpx.AsyncClient(base_url=base, timeout=120) as http:
        hello = await ws.recv()
        spec = json.loads(hello)
        fetched = len(hello)
        params = {"factor": factor, "format": spec["frame_sets"]["format"], "quality": spec["frame_sets"]["quality"]}
        for frame in ["background", *range(spec["frames"])]:
            r = await http.get(spec["frame_sets"]["url"].replace("{frame}", str(frame)), params=params)
            r.raise_for_status()
            fetched += len(r.content)
        await loaded.put(fetched)
        await stop.wait()
    return {"bytes": fetched}


async def live_browser_viewer(base: str, rig_id: str, stop: asyncio.Event, opened: asyncio.Queue) -> dict:
    """A browser-rendering viewer of the live stream, without drawing: counts the frame sets and bytes it gets."""
    ws_url = f"{base.replace('http', 'ws')}/v1/rigs/{rig_id}/view?source=live&render=browser"
    async with websockets.connect(ws_url, max_size=None) as ws:
        await opened.put(1)
        sets = received = 0
        while not stop.is_set():
            try:
                message = await asyncio.wait_for(ws.recv(), 0.5)
            except asyncio.TimeoutError:
                continue
            received += len(message)
            sets += isinstance(message, bytes)
    return {"sets": sets, "bytes": received}


async def paced_pusher(base: str, rig_id: str, sets: list[list[bytes]], background: list[bytes], rate: float,
                       stop: asyncio.Event) -> dict:
    """Live ingest at ``rate`` sets per second (the background set first), each waiting for its ack."""
    from benchmarks.streaming import frame_set_message

    async with websockets.connect(f"{base.replace('http', 'ws')}/v1/rigs/{rig_id}/live", max_size=None) as ws:
        json.loads(await ws.recv())
        await ws.send(frame_set_message(background, 1, background=True))
        await ws.recv()
        seq, t0 = 1, time.perf_counter()
        while not stop.is_set():
            seq += 1
            await ws.send(frame_set_message(sets[seq % len(sets)], seq))
            reply = json.loads(await ws.recv())
            if reply.get("type") != "ack":
                raise RuntimeError(reply)
            await asyncio.sleep(max(0.0, t0 + (seq - 1) / rate - time.perf_counter()))
    return {"sets": seq - 1}


async def measure_recording(base: str, pid: int, rig_id: str, rec: dict, n: int, factor: int, seconds: float) -> dict:
    from harness.proc import tree_cpu_seconds

    stop, loaded = asyncio.Event(), asyncio.Queue()
    cpu0, t0 = tree_cpu_seconds(pid), time.perf_counter()
    tasks = [asyncio.create_task(recording_viewer(base, rig_id, rec["id"], factor, stop, loaded)) for _ in range(n)]
    sizes = [await loaded.get() for _ in range(n)]
    load_cpu, load_s = tree_cpu_seconds(pid) - cpu0, time.perf_counter() - t0
    cpu1, t1 = tree_cpu_seconds(pid), time.perf_counter()
    await asyncio.sleep(seconds)
    steady = (tree_cpu_seconds(pid) - cpu1) / (time.perf_counter() - t1)
    stop.set()
    await asyncio.gather(*tasks)
    return {"viewers": n, "load_cpu_s": load_cpu, "load_s": load_s, "bytes_per_viewer": statistics.mean(sizes or [0]),
            "steady_cores": steady}


async def measure_live(base: str, pid: int, rig_id: str, sets, background, n: int, seconds: float) -> dict:
    from harness.proc import tree_cpu_seconds

    stop, opened = asyncio.Event(), asyncio.Queue()
    viewers = [asyncio.create_task(live_browser_viewer(base, rig_id, stop, opened)) for _ in range(n)]
    for _ in range(n):
        await opened.get()
    push = asyncio.create_task(paced_pusher(base, rig_id, sets, background, LIVE_RATE, stop))
    await asyncio.sleep(2.0)
    cpu0, t0 = tree_cpu_seconds(pid), time.perf_counter()
    await asyncio.sleep(seconds)
    cores = (tree_cpu_seconds(pid) - cpu0) / (time.perf_counter() - t0)
    stop.set()
    pushed = await push
    got = await asyncio.gather(*viewers)
    wall = seconds + 2.0
    return {"viewers": n, "server_cores": cores, "cpu_ms_per_set": cores * 1e3 / LIVE_RATE,
            "sets_pushed": pushed["sets"], "sets_per_viewer": statistics.mean([g["sets"] for g in got]) if got else 0,
            "bytes_per_viewer_per_s": statistics.mean([g["bytes"] for g in got]) / wall if got else 0.0}


def chromium_recording(base: str, pid: int, rig_id: str, rec: dict, n: int, seconds: float) -> dict:
    """``n`` viewer pages in browser mode (SwiftShader) that step through the recording once (every frame set
    fetched and drawn), then stay open: server CPU while they load and step, and afterwards."""
    from harness.proc import tree_cpu_seconds

    with chromium("swiftshader") as browser:
        cpu0, t0 = tree_cpu_seconds(pid), time.perf_counter()
        pages = []
        for _ in range(n):
            page = browser.new_page(viewport={"width": 1100, "height": 800})
            page.goto(f"{base}/viewer/?rig={rig_id}&source={rec['id']}&render=browser")
            pages.append(page)
        for page in pages:
            page.wait_for_function("() => viewerState.ready && viewerState.received > 0", timeout=600_000)
        for frame in range(1, rec["frames"]):  # every page steps through the recording, each frame drawn
            for page in pages:
                page.locator("#frame").fill(str(frame))
            for page in pages:
                page.wait_for_function(f"() => viewerState.frame === {frame} && viewerState.local.shown?.endsWith"
                                       f"('/{frame}') && !viewerState.drawing && !viewerState.dirty", timeout=600_000)
        load_cpu, load_s = tree_cpu_seconds(pid) - cpu0, time.perf_counter() - t0
        fetched = [page.evaluate("viewerState.local.bytes.fetched") for page in pages]
        cpu1, t1 = tree_cpu_seconds(pid), time.perf_counter()
        time.sleep(seconds)
        steady = (tree_cpu_seconds(pid) - cpu1) / (time.perf_counter() - t1)
        errors = sum(page.evaluate("viewerState.errors.length") for page in pages)
    return {"viewers": n, "load_cpu_s": load_cpu, "load_s": load_s, "bytes_per_viewer": statistics.mean(fetched),
            "steady_cores": steady, "errors": errors}


def cost(quick: bool, chromium_viewers: list[int]) -> tuple[dict, str]:
    from benchmarks.streaming import demo_recording, live_frame_sets, run_config
    from harness.servers import CHECKOUT_KERNEL_CACHE, serve_app

    seconds = 10.0 if quick else 30.0
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="sweepcast-bench-") as tmp:
        env = {"SWEEPCAST_DATA_DIR": str(Path(tmp) / "data"), "SWEEPCAST_NUMBA_CACHE_DIR": str(CHECKOUT_KERNEL_CACHE)}
        with serve_app(env, log=Path(tmp) / "server.log") as app:
            pid = app.proc.pid
            with httpx.Client(base_url=app.base, timeout=30) as http:
                deadline = time.monotonic() + 900
                while not (found := demo_recording(http)) and time.monotonic() < deadline:
                    time.sleep(0.5)
                rig_id, rec = found
                rig = rig_from_dict(http.get(f"/v1/rigs/{rig_id}").json()["calibration"])
            factor = source_factor(rig, 640, 480)
            settled = settle(app.base, pid)
            idle = asyncio.run(measure_recording(app.base, pid, rig_id, rec, 0, factor, seconds))["steady_cores"]
            print(json.dumps({"idle_cores": idle}), flush=True)
            recording = [asyncio.run(measure_recording(app.base, pid, rig_id, rec, n, factor, seconds))
                         for n in COST_VIEWERS]
            for row in recording:
                print(json.dumps(row), flush=True)
            pages = [chromium_recording(app.base, pid, rig_id, rec, n, seconds) for n in chromium_viewers]
            for row in pages:
                print(json.dumps(row), flush=True)
            ws = app.base.replace("http", "ws")
            server_view = asyncio.run(run_config(f"{ws}/v1/rigs/{rig_id}/view?source={rec['id']}", 1, (640, 480),
                                                 seconds, pid, frames=rec["frames"]))
            background, sets = live_frame_sets(rig, 4 if quick else 12)
            live_rows = [asyncio.run(measure_live(app.base, pid, rig_id, sets, background, n, seconds))
                         for n in (0, *COST_VIEWERS)]
            for row in live_rows:
                print(json.dumps(row), flush=True)
    set_bytes = statistics.mean(sum(len(j) for j in s) for s in sets)
    md = [f"Load average before the run: {load_before:.1f}; the server's start-up work settled first "
          f"({settled['seconds']:.0f} s{'' if settled['quiet'] else ', never quiet'}). Demo rig: 10 cameras 640x480, recording of "
          f"{rec['frames']} frames; browser viewers at 640x480 (frame sets at source factor {factor}, PNG, the "
          f"default). Idle server (no viewer): {100 * idle:.2f} % of a core.", "",
          "Recording, protocol clients (each loads the background and every frame set once, as the page does, then "
          f"stays connected {seconds:g} s; nothing more is asked: the browser's cache holds the immutable frame sets):",
          "", md_table(["viewers", "server CPU-s to load them all", "load wall s", "MB per viewer",
                        "steady server % of a core"],
                       [[r["viewers"], r["load_cpu_s"], r["load_s"], r["bytes_per_viewer"] / 1e6,
                         100 * r["steady_cores"]] for r in recording])]
    if pages:
        md += ["", "Recording, viewer pages in headless Chromium (SwiftShader; each steps through the recording once, "
                   "every frame drawn, then stays open):", "",
               md_table(["pages", "server CPU-s while they load and step through", "wall s", "MB per page",
                         "steady server % of a core", "page errors"],
                        [[r["viewers"], r["load_cpu_s"], r["load_s"], r["bytes_per_viewer"] / 1e6,
                          100 * r["steady_cores"], r["errors"]] for r in pages])]
    md += ["", f"Anchor, the same run: one server-rendered viewer of the recording at 640x480 (closed loop): "
               f"{server_view['fps']:.1f} fps, {100 * server_view['server_cpu_cores']:.0f} % of a core "
               f"({1e3 * server_view['server_cpu_cores'] / max(server_view['fps'], 1e-9):.0f} ms CPU per frame).", "",
           f"Live stream, {LIVE_RATE:g} frame sets/s pushed (10 JPEG cameras, {set_bytes / 1e3:.0f} kB per set), browser "
           "viewers receiving every set:", "",
           md_table(["viewers", "server % of a core", "CPU ms per set", "sets per viewer", "kB/s per viewer"],
                    [[r["viewers"], 100 * r["server_cores"], r["cpu_ms_per_set"], r["sets_per_viewer"],
                      r["bytes_per_viewer_per_s"] / 1e3] for r in live_rows])]
    extra32 = next(r for r in recording if r["viewers"] == 32)["steady_cores"] - idle
    md.append(f"\nGoal: 32 browser viewers of a cached recording cost the server < 5 % of one core: "
              f"{100 * extra32:.2f} % over the idle server's {100 * idle:.2f} % (Ray's own processes) "
              f"({'met' if extra32 < 0.05 else 'missed'}).")
    return {"load_before": load_before, "settle": settled, "idle_cores": idle, "recording": recording, "pages": pages,
            "server_viewer": server_view, "live": live_rows, "set_bytes": set_bytes}, "\n".join(md)


# --- interaction latency ------------------------------------------------------------------------------
def drags(page, canvas: str, count: int, mode: str) -> list[float]:
    """``count`` small drags on ``canvas``, each waited for until its frame is on screen; the page's own
    pointer-to-frame latencies (ms)."""
    page.evaluate("viewerState.latencies = []")
    box = page.locator(canvas).bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    done = ("!viewerState.drawing && !viewerState.dirty" if mode == "browser"
            else "viewerState.inFlight === null && !viewerState.dirty")
    for k in range(count):
        received = page.evaluate("viewerState.received")
        page.mouse.move(x, y)
        page.mouse.down()
        page.mouse.move(x + (12 if k % 2 == 0 else -12), y)
        page.mouse.up()
        page.wait_for_function(f"() => viewerState.received > {received} && {done}", timeout=600_000)
    return page.evaluate("viewerState.latencies")


def latency(quick: bool, size: str) -> tuple[dict, str]:
    from benchmarks.streaming import demo_recording
    from harness.servers import CHECKOUT_KERNEL_CACHE, serve_app

    count = 8 if quick else 20
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="sweepcast-bench-") as tmp:
        env = {"SWEEPCAST_DATA_DIR": str(Path(tmp) / "data"), "SWEEPCAST_NUMBA_CACHE_DIR": str(CHECKOUT_KERNEL_CACHE)}
        with serve_app(env, log=Path(tmp) / "server.log") as app, chromium("swiftshader") as browser:
            with httpx.Client(base_url=app.base, timeout=30) as http:
                deadline = time.monotonic() + 900
                while not (found := demo_recording(http)) and time.monotonic() < deadline:
                    time.sleep(0.5)
            rig_id, rec = found
            settle(app.base, app.proc.pid)
            page = browser.new_page(viewport={"width": 1400, "height": 1000})
            page.goto(f"{app.base}/viewer/?rig={rig_id}&source={rec['id']}&render=browser")
            page.select_option("#size", size)
            page.wait_for_function("() => viewerState.ready && viewerState.received > 0", timeout=600_000)
            gpu = page.evaluate("viewerState.gpu")
            browser_ms = drags(page, "#glview", count, "browser")
            page.click("#advanced summary")  # the Render switch is among the advanced ones
            page.select_option("#render-choice", "server")
            page.wait_for_function("() => viewerState.mode === 'server' && viewerState.ready", timeout=600_000)
            drags(page, "#view", 3, "server")  # the session's first renders load its frames
            server_ms = drags(page, "#view", count, "server")
    pct = lambda v, q: float(np.percentile(v, q))  # noqa: E731
    rows = [["browser (" + gpu.split("(")[0].strip() + ", " + ("SwiftShader" if "SwiftShader" in gpu else "GPU") + ")",
             len(browser_ms), pct(browser_ms, 50), pct(browser_ms, 95)],
            ["server (2 cores, JPEG over the socket)", len(server_ms), pct(server_ms, 50), pct(server_ms, 95)]]
    md = [f"Load average before the run: {load_before:.1f}. WebGL: {gpu}. View {size}, 48 planes, coarse-to-fine, "
          "the demo rig (10 cameras). Each drag moves the orbit by a few degrees; the page measures from the pointer "
          "move to the frame drawn on its canvas (browser: the render on this machine's WebGL; server: the viewpoint "
          "sent, rendered, JPEG back, decoded, drawn).", "",
          md_table(["mode", "drags", "p50 ms", "p95 ms"], rows)]
    return {"load_before": load_before, "gpu": gpu, "size": size, "browser_ms": browser_ms,
            "server_ms": server_ms}, "\n".join(md)


# --- first frame without a GPU ------------------------------------------------------------------------------
def first_frame(quick: bool) -> tuple[dict, str]:
    from benchmarks.streaming import demo_recording
    from harness.servers import CHECKOUT_KERNEL_CACHE, serve_app

    repeats = 2 if quick else 5
    load_before = os.getloadavg()[0]
    rows, runs = [], {}
    with tempfile.TemporaryDirectory(prefix="sweepcast-bench-") as tmp:
        env = {"SWEEPCAST_DATA_DIR": str(Path(tmp) / "data"), "SWEEPCAST_NUMBA_CACHE_DIR": str(CHECKOUT_KERNEL_CACHE)}
        with serve_app(env, log=Path(tmp) / "server.log") as app:
            with httpx.Client(base_url=app.base, timeout=30) as http:
                deadline = time.monotonic() + 900
                while not (found := demo_recording(http)) and time.monotonic() < deadline:
                    time.sleep(0.5)
            rig_id, rec = found
            settled = settle(app.base, app.proc.pid)
            for label, webgl, query in (("plain headless (--disable-gpu)", "none", ""),
                                        ("WebGL2 on SwiftShader", "swiftshader", ""),
                                        ("WebGL2 on SwiftShader, ?render=server", "swiftshader", "&render=server")):
                times, modes, reasons, levels = [], set(), set(), set()
                with chromium(webgl) as browser:
                    for _ in range(repeats):  # a fresh page each time, the server's session warm after the first
                        page = browser.new_page(viewport={"width": 1280, "height": 900})
                        page.goto(f"{app.base}/viewer/?rig={rig_id}&source={rec['id']}{query}")
                        page.wait_for_function("() => viewerState.firstFrameAt !== null", timeout=120_000)
                        times.append(page.evaluate("viewerState.firstFrameAt"))
                        modes.add(page.evaluate("viewerState.mode"))
                        reasons.add(page.locator("#mode").inner_text())
                        levels.add(page.locator("#quality-shown").inner_text())
                        page.close()
                runs[label] = {"ms": times, "modes": sorted(modes), "shown": sorted(reasons), "quality": sorted(levels)}
                print(json.dumps({label: runs[label]}), flush=True)
                rows.append([label, len(times), float(np.median(times)), max(times), ", ".join(sorted(reasons)),
                             ", ".join(sorted(levels))])
    worst = max(r[2] for r in rows[:2])
    md = [f"Load average before the run: {load_before:.1f}; the server's start-up work settled first "
          f"({settled['seconds']:.0f} s). The demo recording at the page's default size, Render and Quality auto as a "
          "new user opens the page; each row opens a fresh page several times in one headless Chromium (the first "
          "also starts the viewer's session on the server). ms: from the page's navigation to its first view drawn "
          "(`viewerState.firstFrameAt`).", "",
          md_table(["browser", "pages", "median ms", "max ms", "the page says it renders on", "quality shown"], rows),
          "", f"Goal: the first frame <= {FIRST_FRAME_GOAL_MS:g} ms without a GPU (median, the two auto rows): "
              f"{worst:.0f} ms ({'met' if worst <= FIRST_FRAME_GOAL_MS else 'missed'})."]
    return {"load_before": load_before, "settle": settled, "runs": runs, "quick": quick}, "\n".join(md)


# --- flicker ----------------------------------------------------------------------------------------
FLICKER_AZIMUTHS = (-13.0, -33.0)


def flicker_of(images: list[np.ndarray], still: list[np.ndarray]) -> float:
    """Mean over consecutive frames of the mean absolute change (levels) on the still pixels."""
    return float(np.mean([np.abs(b.astype(float) - a).mean(axis=2)[m].mean()
                          for a, b, m in zip(images, images[1:], still)]))


def flicker(quick: bool) -> tuple[dict, str]:
    size = (160, 120) if quick else (320, 240)
    count = 6 if quick else 12
    rig = demo_rig(10, size)
    scenes = [demo_scene((f % count) / count) for f in range(count + 1)]
    views = [render_views(scene, list(rig.cameras)) for scene in scenes]
    sets = [[v.image for v in each] for each in views]
    backgrounds = [v.background for v in views[0]]
    factor = source_factor(rig, *size)
    small = shrunk_rig(rig, factor)
    atlases = [frame_atlas(frames, rig, factor) for frames in sets]
    background_atlas, spec = frame_atlas(backgrounds, rig, factor), render_spec(rig)
    rows, out = [], {}
    with static_site() as base, chromium() as browser:
        page = browser.new_page()
        page.goto(f"{base}/render/renderer.js")
        for azimuth in FLICKER_AZIMUTHS:
            virtual = orbit_camera(orbit_frame(rig), Orbit(azimuth=azimuth), 50.0, size)
            truths = [render_views(scene, [virtual], with_background=False)[0].image for scene in scenes]
            still = [still_between(a, b) for a, b in zip(truths, truths[1:])]
            for level in ("fast", "best"):
                options = {"planes": 48, "coarse_to_fine": True, **LEVELS[level]}
                server = SweepRenderer(small, shrunk_images(sets[0], small), device="cpu",
                                       backgrounds=shrunk_images(backgrounds, small))
                served: dict[str, list[np.ndarray]] = {"searched": [], "held": []}
                previous = None
                for k, frames in enumerate(sets):
                    if k:
                        server.set_frames(shrunk_images(frames, small))
                    served["searched"].append(server.render(virtual, RenderOptions(**options)).image)
                    previous = server.render(virtual, RenderOptions(**options), previous=previous)
                    served["held"].append(previous.image)
                drawn = {}
                for how in ("searched", "held"):
                    b = render_in_browser(page, spec, atlases[0], background_atlas, virtual, factor, options,
                                          later=tuple(atlases[1:]), hold=how == "held")
                    drawn[how] = [*b["images"], b["image"]]
                entry = {f"{who} {how}": flicker_of(images[how], still)
                         for who, images in (("server", served), ("browser", drawn)) for how in ("searched", "held")}
                entry["browser_vs_server_db"] = float(np.mean([psnr(a, b) for a, b in zip(drawn["held"],
                                                                                            served["held"])]))
                out[f"{azimuth:g} {level}"] = entry
                print(json.dumps({f"{azimuth:g} {level}": entry}), flush=True)
                rows.append([f"azimuth {azimuth:g}", level, entry["server searched"], entry["server held"],
                             entry["browser searched"], entry["browser held"], entry["browser_vs_server_db"]])
    md = (f"The demo recording ({count} frames of the ball circling, {size[0]}x{size[1]}, 48 planes, "
          "coarse-to-fine), one fixed view per row, drawn frame set after frame set by the server's renderer and by "
          "the browser's (SwiftShader): the depth searched anew each time, or held where the nearest cameras saw no "
          "change since the last frame (`workers/sweep/temporal.py`, `app/static/render/temporal.js`). Flicker: the "
          "mean absolute change (levels) between consecutive frames on the pixels whose true colour stayed the same; "
          "PSNR: the browser's held frames against the server's.\n\n"
          + md_table(["view", "level", "server, searched", "server, held", "browser, searched", "browser, held",
                      "browser vs server held, PSNR dB"], rows))
    return {"size": list(size), "frames": count, "views": out}, md


sections = Sections("streaming_browser", __doc__)
sections.parser.add_argument("--quick", action="store_true", help="half-size views / fewer repeats")
sections.parser.add_argument("--webgl", choices=["swiftshader", "gpu"], default="swiftshader",
                             help="fps: Chromium's WebGL on SwiftShader (any machine) or on this machine's GPU")
sections.parser.add_argument("--size", default="320x240", help="latency: the view size (an option of the page's list)")
sections.parser.add_argument("--chromium", type=int, nargs="*", default=[1, 8],
                             help="cost: numbers of Chromium viewer pages (default 1 8)")
sections.part("quality", "the browser's picture against the server's on held-out views", lambda a: quality(a.quick))
sections.part("fps", "browser render time per view size, planes and options (and the server's)",
              lambda a: fps(a.quick, a.webgl),
              results=lambda a: "streaming_browser_fps" + ("" if a.webgl == "swiftshader" else "_gpu"))
sections.part("cost", "what browser-rendering viewers cost the server", lambda a: cost(a.quick, a.chromium))
sections.part("latency", "pointer move to frame on screen, browser mode against server mode",
              lambda a: latency(a.quick, a.size))
sections.part("flicker", "the demo recording through a fixed view: flicker, searched and held, server and browser",
              lambda a: flicker(a.quick))
sections.part("first_frame", "the viewer page's first view without a GPU", lambda a: first_frame(a.quick))


if __name__ == "__main__":
    sys.exit(sections.main())
