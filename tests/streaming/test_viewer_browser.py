"""The browser viewer end to end in headless Chromium (Debian's package, driven by Playwright)."""
import base64
import json
import os
import shutil
import time
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest

from harness.servers import serve_in_thread
from harness.takes import rig_json, zip_bytes

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (the test extra)")
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
pytestmark = pytest.mark.skipif(not Path(CHROMIUM).exists(), reason="Debian's chromium is not installed")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync"]


@pytest.fixture
def server(ray_local, settings_factory, take):
    """The service with a rig and a ready recording (the small take), viewer at 320x240."""
    with serve_in_thread(settings_factory(session_idle_seconds=5.0, viewer_size="320x240")) as base:
        with httpx.Client(base_url=base, timeout=30) as http:
            rig_id = http.post("/v1/rigs", files={"files": ("rig.json", rig_json(take.rig))}).json()["id"]
            rec = http.post(f"/v1/rigs/{rig_id}/recordings", files={"archive": ("t.zip", zip_bytes(take))}).json()
            while http.get(f"/v1/rigs/{rig_id}/recordings/{rec['id']}").json()["state"] == "processing":
                time.sleep(0.1)
        yield base, rig_id


def canvas(page) -> np.ndarray:
    url = page.evaluate("document.getElementById('view').toDataURL('image/png')")
    data = base64.b64decode(url.split(",", 1)[1])
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR).astype(int)


def settled(page, after: int) -> None:
    """Wait until a frame after the first ``after`` has arrived and nothing is in flight or pending."""
    page.wait_for_function(
        f"() => {{ const s = window.viewerState; return s.received > {after} && s.inFlight === null && !s.dirty; }}",
        timeout=60_000)


def test_viewer_connects_orbits_with_a_drag_and_toggles_the_overlay(server, tmp_path, monkeypatch):
    base, rig_id = server
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.goto(f"{base}/viewer/?rig={rig_id}")
            settled(page, 0)
            assert page.locator("#state").inner_text() == "ready"
            first = canvas(page)
            assert first.shape == (240, 320, 3) and first.max() > 0
            received = page.evaluate("window.viewerState.received")

            box = page.locator("#view").bounding_box()
            x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
            page.mouse.move(x, y)
            page.mouse.down()
            page.mouse.move(x + 150, y + 20, steps=10)
            page.mouse.up()
            settled(page, received)
            dragged = canvas(page)
            assert page.evaluate("window.viewerState.azimuth") < -30
            assert np.abs(dragged - first).mean() > 2  # the picture changed

            received = page.evaluate("window.viewerState.received")
            page.select_option("#overlay", "regions")
            settled(page, received)
            assert page.evaluate("window.viewerState.lastHeader.overlay") == "regions"
            overlaid = canvas(page)
            surface = dragged.max(axis=2) > 0
            assert np.abs(overlaid - dragged)[surface].mean() > 10  # the surface is tinted by region
            received = page.evaluate("window.viewerState.received")
            page.select_option("#overlay", "none")
            settled(page, received)
            assert np.abs(canvas(page) - dragged).mean() < 1  # toggled back: the same view

            page.click("#advanced summary")  # the expert switches
            derived = page.evaluate("window.viewerState.lastHeader.d_bnd")
            assert derived > 0 and page.locator("#dbnd-value").inner_text().endswith("(auto)")
            received = page.evaluate("window.viewerState.received")
            page.locator("#dbnd").fill("-1")  # the slider sets D_bnd = 10**-1 and leaves auto
            settled(page, received)
            assert page.evaluate("window.viewerState.lastHeader.d_bnd") == 0.1
            assert not page.locator("#dbnd-auto").is_checked()

            assert page.locator("#fps").inner_text() != "–"
            assert page.locator("#latency").inner_text().startswith("p50")
            assert page.evaluate("window.viewerState.errors.length") == 0
        finally:
            browser.close()


# --- the first-run demo, as a new user sees it ------------------------------------------------------
def channel_agreement(image: np.ndarray, mask: np.ndarray) -> float:
    """Mean correlation, over ``mask`` (H, W) bool, between the x/y Sobel gradients of the colour
    channels of ``image`` (H, W, 3): about 1 for photographs (their edges are mostly changes of
    brightness, the same in every channel), about 0 for independent per-channel colour noise (the old
    demo's blotchy textures measured -0.08 in a 480x360 view, the photographic studio 0.86)."""
    grads = []
    for c in range(3):
        ch = image[..., c].astype(np.float32)
        grads.append(np.concatenate([cv2.Sobel(ch, cv2.CV_32F, 1, 0)[mask], cv2.Sobel(ch, cv2.CV_32F, 0, 1)[mask]]))
    return float(np.mean([np.corrcoef(grads[a], grads[b])[0, 1] for a, b in ((0, 1), (1, 2), (0, 2))]))


@pytest.fixture
def demo_server(ray_local, settings_factory):
    """A first start with the demo rig on (the real first-run path), once its recording is ready."""
    settings = settings_factory(session_idle_seconds=10.0, demo_rig=True)
    with serve_in_thread(settings) as base:
        with httpx.Client(base_url=base, timeout=30) as http:
            deadline = time.monotonic() + 600
            while time.monotonic() < deadline:
                rigs = [r for r in http.get("/v1/rigs").json()["rigs"] if r["demo"]]
                recs = http.get(f"/v1/rigs/{rigs[0]['id']}").json()["recordings"] if rigs else []
                if recs and recs[0]["state"] != "processing":
                    assert recs[0]["state"] == "ready", recs[0]
                    break
                time.sleep(0.5)
            else:
                raise AssertionError("the demo recording was not ready in 10 minutes")
        yield base, settings


def test_the_first_run_demo_looks_like_a_studio_at_the_default_size(demo_server, tmp_path, monkeypatch):
    """Screenshot of the viewer on the first-run demo: the view comes at the configured default size
    (not 320x240 stretched), is photographic (channel gradients agree, unlike colour noise) and shows
    a floor (the lower third of the view mostly surface, not the black of culled space)."""
    base, settings = demo_server
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    width, height = settings.viewer_size_px
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.goto(f"{base}/viewer/")
            settled(page, 0)
            assert page.locator("#rig").input_value() and page.locator("#size").input_value() == f"{width}x{height}"
            view = canvas(page).astype(np.uint8)
            shot = Path(os.environ.get("SWEEPCAST_TEST_SCREENSHOTS", tmp_path)) / "viewer_demo.png"
            shot.parent.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(shot))
            assert shot.stat().st_size > 10_000
            assert page.evaluate("window.viewerState.errors.length") == 0
        finally:
            browser.close()
    assert view.shape == (height, width, 3)
    surface = cv2.erode((view.max(axis=2) > 8).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert surface.mean() > 0.3
    assert channel_agreement(view, surface) > 0.5
    assert surface[2 * height // 3:].mean() > 0.6  # the stage floor fills the lower third


# --- rendering in the browser ---------------------------------------------------------------------
def drawn(page, after: int) -> None:
    """Wait until the browser renderer has drawn a view after the first ``after`` and nothing is pending."""
    page.wait_for_function(
        f"() => {{ const s = window.viewerState; return s.mode === 'browser' && s.received > {after} && !s.drawing "
        f"&& !s.dirty; }}", timeout=120_000)


def gl_canvas(page) -> np.ndarray:
    url = page.evaluate("document.getElementById('glview').toDataURL('image/png')")
    return cv2.imdecode(np.frombuffer(base64.b64decode(url.split(",", 1)[1]), np.uint8), cv2.IMREAD_COLOR)


def atlas_cells(data: bytes, rig) -> list[np.ndarray]:
    """The camera images of a frame-set atlas (factor 1)."""
    from workers.streaming.browser import atlas_columns

    atlas = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    w, h, cols = rig.cameras[0].width, rig.cameras[0].height, atlas_columns(len(rig))
    return [atlas[(i // cols) * h:(i // cols + 1) * h, (i % cols) * w:(i % cols + 1) * w].copy() for i in range(len(rig))]


def test_the_viewer_renders_in_the_browser_from_cached_frame_sets(server, take):
    """?render=browser on a machine without a GPU (SwiftShader): the page says so, draws the server's picture of
    the same viewpoint (from JPEG frame sets) at the quality level it holds the target rate with (auto: fast here,
    as it measured), fetches each frame set once, keeps the orbit on the cameras' arc unless freed, renders the best
    level and an advanced switch's override too, starts no session on the server, and switches to server rendering
    on request."""
    from harness.browser import chromium
    from workers.common.imagemetrics import psnr
    from workers.streaming.params import Orbit
    from workers.streaming.viewpoint import orbit_camera, orbit_frame
    from workers.sweep.renderer import SweepRenderer

    base, rig_id = server
    with chromium("swiftshader") as browser:
        page = browser.new_page(viewport={"width": 1280, "height": 900})
        page.goto(f"{base}/viewer/?rig={rig_id}&render=browser")
        drawn(page, 0)
        assert "SwiftShader" in page.locator("#mode").inner_text()
        assert page.locator("#render-choice").input_value() == "browser"
        # auto quality: SwiftShader misses the target rate even at the fast level, which it then keeps (forced here)
        assert page.evaluate("viewerState.level") == "fast"
        assert page.locator("#quality-shown").inner_text() == "fast: semi-global depth (auto)"
        state = page.evaluate("({az: viewerState.azimuth, el: viewerState.elevation, d: viewerState.distance,"
                              " sets: viewerState.local.bytes.sets, dbnd: viewerState.lastInfo.d_bnd})")
        assert state["sets"] == 2  # the background and frame 0, nothing per view
        camera = orbit_camera(orbit_frame(take.rig), Orbit(azimuth=state["az"], elevation=state["el"],
                                                            distance=state["d"]), 50.0, (320, 240))
        with httpx.Client(base_url=base, timeout=30) as http:
            assert not [s for s in http.get("/v1/sessions").json()["sessions"] if s["rig_id"] == rig_id]
            recording = http.get(f"/v1/rigs/{rig_id}").json()["recordings"][0]["id"]
            sent = [atlas_cells(http.get(f"/v1/rigs/{rig_id}/recordings/{recording}/frames/{f}").content, take.rig)
                    for f in (0, "background")]
        # the server's renderer on the frames the browser was sent (JPEG, decoded here) draws the same picture
        expected = SweepRenderer(take.rig, sent[0], backgrounds=sent[1], device="cpu").render(
            camera, coarse_to_fine=True, aggregation="sgm")
        first = gl_canvas(page)
        assert psnr(expected.image, first) > 35
        assert state["dbnd"] == pytest.approx(expected.d_bnd, rel=1e-3)

        received = page.evaluate("viewerState.received")
        box = page.locator("#glview").bounding_box()
        x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        page.mouse.move(x, y)
        page.mouse.down()
        page.mouse.move(x + 600, y, steps=6)  # 180 degrees: far past the cameras' 90-degree arc
        page.mouse.up()
        drawn(page, received)
        coverage = page.evaluate("viewerState.coverage")
        assert page.evaluate("viewerState.azimuth") == pytest.approx(coverage["azimuth"][0])
        assert np.abs(gl_canvas(page).astype(int) - first).mean() > 2
        assert page.locator("#coverage").is_hidden() and page.evaluate("viewerState.latencies.length") > 0

        page.check("#free-orbit")
        received = page.evaluate("viewerState.received")
        page.mouse.move(x, y)
        page.mouse.down()
        page.mouse.move(x + 150, y, steps=3)
        page.mouse.up()
        drawn(page, received)
        assert page.locator("#coverage").is_visible()

        received = page.evaluate("viewerState.received")
        page.locator("#frame").fill("1")
        drawn(page, received)
        page.locator("#frame").fill("0")
        drawn(page, received + 1)
        assert page.evaluate("viewerState.local.bytes.sets") == 3  # frame 1 fetched once, frame 0 kept
        assert page.evaluate("viewerState.errors.length") == 0

        received = page.evaluate("viewerState.received")
        page.select_option("#quality", "best")  # the occlusion fill and visibility-aware colour: in the browser too
        drawn(page, received)
        assert page.evaluate("viewerState.mode") == "browser" and page.evaluate("viewerState.level") == "best"
        assert page.locator("#quality-shown").inner_text() == "best: semi-global depth, occlusions filled"
        view = page.evaluate("({az: viewerState.azimuth, el: viewerState.elevation, d: viewerState.distance,"
                             " frame: viewerState.frame})")
        assert view["frame"] == 0
        camera = orbit_camera(orbit_frame(take.rig), Orbit(azimuth=view["az"], elevation=view["el"],
                                                            distance=view["d"]), 50.0, (320, 240))
        expected = SweepRenderer(take.rig, sent[0], backgrounds=sent[1], device="cpu").render(
            camera, coarse_to_fine=True, aggregation="sgm", occlusions="fill")
        assert psnr(expected.image, gl_canvas(page)) > 35

        page.click("#advanced summary")  # the expert switches: an aggregation of one's own overrides the level's
        received = page.evaluate("viewerState.received")
        page.select_option("#aggregation", "window")
        drawn(page, received)
        assert page.evaluate("viewerState.mode") == "browser"
        assert page.locator("#quality-shown").inner_text().startswith("custom: window depth")
        expected = SweepRenderer(take.rig, sent[0], backgrounds=sent[1], device="cpu").render(
            camera, coarse_to_fine=True, aggregation="window", occlusions="fill")
        assert psnr(expected.image, gl_canvas(page)) > 35

        page.select_option("#render-choice", "server")
        settled(page, 0)
        assert page.evaluate("viewerState.mode") == "server" and page.locator("#view").is_visible()
        assert page.locator("#mode").inner_text() == "the server"


def test_a_browser_whose_webgl_runs_on_the_cpu_asks_the_server_at_once(server):
    """Render auto on SwiftShader (WebGL2 on the CPU): the page opens the server's session straight away, without
    loading frame sets into the browser or timing a render there, says why, and shows the quality level the server
    drew (auto) from the levels the hello names."""
    from harness.browser import chromium
    from workers.streaming.quality import LEVELS
    from workers.streaming.rules import choices
    from workers.sweep.renderer import RenderOptions

    base, rig_id = server
    with chromium("swiftshader") as browser:
        page = browser.new_page(viewport={"width": 1280, "height": 900})
        page.goto(f"{base}/viewer/?rig={rig_id}")
        settled(page, 0)
        assert page.evaluate("viewerState.mode") == "server"
        assert page.locator("#mode").inner_text().startswith("the server (WebGL runs on the CPU here (ANGLE")
        # the menus offer the server's choices (the hello's controls), "as the quality level" first where it may
        options = "(select) => [...select.options].map((o) => o.value)"
        assert page.eval_on_selector("#method", options) == choices(RenderOptions.model_fields["method"])
        assert page.eval_on_selector("#occlusions", options) == ["", *choices(RenderOptions.model_fields["occlusions"])]
        assert page.eval_on_selector("#quality", options) == ["auto", *LEVELS]
        assert page.locator("#planes").input_value() == "48" and page.locator("#planes").get_attribute("max") == "256"
        assert page.evaluate("viewerState.local === null && viewerState.renderTimes.length === 0")
        assert page.evaluate("viewerState.hello.quality_levels") == LEVELS
        header = page.evaluate("viewerState.lastHeader")
        assert header["quality_asked"] == "auto" and header["quality"] in LEVELS
        assert page.locator("#quality-shown").inner_text().endswith("(auto)")
        assert page.evaluate("viewerState.errors.length") == 0


def test_the_browser_renders_the_live_stream_from_relayed_frame_sets(server, take):
    """A live client pushes the empty studio (background) and then frames; a browser-rendering viewer of the live
    source draws each new set with silhouettes from its own background model (started from the server's)."""
    import websockets.sync.client as wsclient

    from harness.browser import chromium
    from harness.takes import frame_set, jpeg

    base, rig_id = server
    with wsclient.connect(f"{base.replace('http', 'ws')}/v1/rigs/{rig_id}/live", max_size=None) as live:
        live.recv()  # hello
        live.send(frame_set([jpeg(b, 98) for b in take.backgrounds], background=True, seq=1))
        assert json.loads(live.recv())["type"] == "ack"
        live.send(frame_set([jpeg(i, 98) for i in take.frames[0]], seq=2))
        assert json.loads(live.recv())["type"] == "ack"
        with chromium("swiftshader") as browser:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.goto(f"{base}/viewer/?rig={rig_id}&source=live&render=browser")
            page.wait_for_function("() => viewerState.ready", timeout=120_000)
            t = time.time()
            live.send(frame_set([jpeg(i, 98) for i in take.frames[1]], seq=3, tolerance=0.02,
                                captured=[t + 0.001 * c for c in range(len(take.rig))]))
            assert json.loads(live.recv())["type"] == "ack"
            page.wait_for_function("() => viewerState.liveSeq !== null && !viewerState.drawing && !viewerState.dirty"
                                   " && viewerState.received > 0", timeout=120_000)
            view = gl_canvas(page)
            assert page.evaluate("viewerState.local.renderer.frames.hasSilhouettes")
            surface = view.max(axis=2) > 8
            assert 0.05 < surface.mean() < 0.9  # the studio's objects, the empty scene around them culled
            assert page.locator("#spread").inner_text() == f"{(len(take.rig) - 1):.1f} ms"  # beside fps
            shown = page.evaluate("viewerState.liveSeq")
            gone = take.rig.names[1]  # a set with a camera gone: said beside fps; this renderer keeps the last whole set
            live.send(frame_set([jpeg(i, 98) for i in take.frames[2]], seq=4, captured=[t + 0.04] * len(take.rig),
                                stale=[gone]))
            assert json.loads(live.recv())["stale"] == [gone]
            page.wait_for_function(f"() => document.getElementById('spread').textContent.includes('stale: {gone}')",
                                   timeout=60_000)
            assert page.evaluate("viewerState.liveSeq") == shown
            assert page.evaluate("viewerState.errors.length") == 0
