"""The review page end to end in headless Chromium (Debian's package, driven by Playwright): keyboard and click."""
from __future__ import annotations

import time

import httpx
import piexif
import pytest

from tests.app.test_review_api import review_photos
from tests.orientation.builders import split_around_app1

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (the test extra)")
from harness.servers import serve_in_thread  # noqa: E402
from tests.streaming.test_viewer_browser import CHROMIUM, CHROMIUM_ARGS, pytestmark  # noqa: E402,F401


def test_a_person_picks_the_upright_turn_with_the_keyboard_and_leaves_one_with_a_click(
        ray_local, settings_factory, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg-config"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg-cache"))
    files = review_photos()
    original = files[0][1][1]
    with serve_in_thread(settings_factory()) as base, httpx.Client(base_url=base, timeout=30) as http:
        job = http.post("/v1/photos/batches", files=files, data={"text": "false"}).json()["id"]
        deadline = time.monotonic() + 120
        while http.get(f"/v1/jobs/{job}").json()["state"] != "succeeded":
            assert time.monotonic() < deadline, http.get(f"/v1/jobs/{job}").json()
            time.sleep(0.2)

        with sync_api.sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
            try:
                page = browser.new_page(viewport={"width": 1100, "height": 800})
                page.goto(f"{base}/review/{job}")
                page.wait_for_function("() => window.reviewState.items.length === 2 && Array.from(document"
                                       ".querySelectorAll('.item:first-child .option img')).every(i => i.complete"
                                       " && i.naturalWidth > 0)", timeout=30_000)
                # the four turns of the first photo show its thumbnail, turned by CSS
                turns = page.eval_on_selector_all(".item:first-child .option img",
                                                  "imgs => imgs.map(i => [i.complete && i.naturalWidth, i.style.transform])")
                assert turns == [[320, "rotate(0deg)"], [320, "rotate(90deg)"], [320, "rotate(180deg)"],
                                 [320, "rotate(270deg)"]]
                page.keyboard.press("Enter")  # no name yet: refused, nothing sent
                page.wait_for_function("() => window.reviewState.errors.length === 1")
                page.fill("#reviewer", "Grace")
                page.keyboard.press("Escape")
                page.locator("body").click(position={"x": 5, "y": 5})
                page.keyboard.press("ArrowRight")  # 0 -> 90 degrees
                page.keyboard.press("Enter")
                page.wait_for_function("() => window.reviewState.items[0].review !== null")
                assert page.evaluate("window.reviewState.current") == 1  # on to the next photo
                page.click(".item:nth-child(2) .option.leave")  # one click: leave it
                page.wait_for_function("() => window.reviewState.items[1].review !== null")
                assert "2 of 2 decided" in page.inner_text("#progress")
                assert "turned 90\u00b0 by Grace" in page.inner_text(".item:first-child .decided")
            finally:
                browser.close()

        entries = http.get(f"/v1/jobs/{job}/results/report.json").json()
        first, second = (e["review"] for e in entries)
        assert first["decided_by"] == "person" and first["reviewer"] == "Grace" and first["rotation_degrees"] == 90
        assert second["reviewer"] == "Grace" and second["action"] == "left_as_is"
        fixed = http.get(f"/v1/jobs/{job}/results/{first['fixed_file']}").content
        assert piexif.load(fixed)["0th"][piexif.ImageIFD.Orientation] == 6
        assert split_around_app1(fixed)[1] == split_around_app1(original)[1]
