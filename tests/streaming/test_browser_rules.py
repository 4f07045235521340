"""The browser renderer follows the server's rules from the hello's render block (workers/streaming/rules.py,
workers/streaming/browser.py render_spec) instead of copies: what it derives from them is what the server derives,
and a value outside the server's choices is refused loudly. Headless Chromium with SwiftShader."""
from __future__ import annotations

import numpy as np
import pytest

from tests.browser import chromium, have_chromium, static_site
from workers.camera import Camera
from workers.streaming.browser import render_spec
from workers.streaming.session import shrunk_rig, source_factor
from workers.sweep.rig import Rig

pytest.importorskip("playwright.sync_api", reason="playwright is not installed (the test extra)")
pytestmark = pytest.mark.skipif(not have_chromium(), reason="Debian's chromium is not installed")


@pytest.fixture(scope="module")
def page():
    with static_site() as base, chromium() as browser:
        p = browser.new_page()
        p.goto(f"{base}/render/renderer.js")  # any page of the site: the modules import from its origin
        yield p


def uneven_rig() -> Rig:
    """Three cameras of different sizes (the smallest decides the factor), odd sizes that round when shrunk."""
    K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    sizes = [(641, 481), (1001, 333), (700, 500)]
    return Rig(tuple(Camera(f"c{i}", K, np.eye(3), np.array([0.3 * i, 0.0, 0.0]), w, h) for i, (w, h) in enumerate(sizes)))


def test_the_browser_sweeps_the_frames_the_server_shrinks_for_every_view_size(page):
    rig = uneven_rig()
    sizes = [(w, h) for w in (16, 40, 79, 80, 81, 106, 107, 160, 213, 214, 320, 641, 900) for h in (16, 41, 42, 83, 111, 166, 333, 400)]
    got = page.evaluate("""async ({spec, sizes}) => {
      const { Rig } = await import("/render/rig.js");
      const rig = new Rig(spec);
      return sizes.map(([w, h]) => {
        const factor = rig.sourceFor(w, h).factor;
        return { factor, cameras: rig.camerasAt(factor).map((c) => ({ K: c.K, width: c.width, height: c.height })) };
      });
    }""", {"spec": render_spec(rig), "sizes": sizes})
    assert [g["factor"] for g in got] == [source_factor(rig, w, h) for w, h in sizes]
    assert len({g["factor"] for g in got}) >= 5  # the sizes reach most factors
    for g in got:
        for mine, theirs in zip(g["cameras"], shrunk_rig(rig, g["factor"]).cameras):
            assert (mine["width"], mine["height"]) == (theirs.width, theirs.height)
            np.testing.assert_array_equal(np.reshape(mine["K"], (3, 3)), theirs.K)


def test_an_option_outside_the_servers_choices_is_refused_naming_them(page):
    spec = render_spec(uneven_rig())
    message = page.evaluate("""async ({spec}) => {
      const { BrowserRenderer } = await import("/render/renderer.js");
      const canvas = document.createElement("canvas");
      const r = await BrowserRenderer.create(canvas.getContext("webgl2"), spec);
      try { r.options({ aggregation: "windowed" }); return null; } catch (error) { return error.message; }
      finally { r.dispose(); }
    }""", {"spec": spec})
    assert message == "aggregation must be one of none, window, sgm; got windowed"
