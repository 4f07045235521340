"""The browser viewer end to end in headless Chromium (Debian's package, driven by Playwright)."""
import base64
import shutil
import socket
import threading
import time
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest

from tests.streaming.capture import rig_json, zip_bytes

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (the test extra)")
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
pytestmark = pytest.mark.skipif(not Path(CHROMIUM).exists(), reason="Debian's chromium is not installed")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync"]


@pytest.fixture
def server(ray_local, settings_factory, take):
    """The service on a free loopback port (uvicorn in a thread), with a rig and a ready recording."""
    import uvicorn

    from app.main import create_app

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    app = create_app(settings_factory(session_idle_seconds=5.0))
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    base = f"http://127.0.0.1:{port}"
    with httpx.Client(base_url=base, timeout=30) as http:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                if http.get("/readyz").status_code == 200:
                    break
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        rig_id = http.post("/v1/rigs", files={"files": ("rig.json", rig_json(take.rig))}).json()["id"]
        rec = http.post(f"/v1/rigs/{rig_id}/recordings", files={"archive": ("t.zip", zip_bytes(take))}).json()
        while http.get(f"/v1/rigs/{rig_id}/recordings/{rec['id']}").json()["state"] == "processing":
            time.sleep(0.1)
    yield base, rig_id
    server.should_exit = True
    thread.join(30)


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
