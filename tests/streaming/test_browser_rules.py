"""The browser renderer follows the server's rules from the hello's render block (workers/streaming/rules.py,
workers/streaming/browser.py render_spec) instead of copies: what it derives from them is what the server derives,
and a value outside the server's choices is refused loudly; its passes fail loudly on a uniform they do not take, and
keep their render targets. Headless Chromium with SwiftShader."""
from __future__ import annotations

import numpy as np
import pytest

from harness.browser import have_chromium, png_b64
from tests.streaming.test_browser_renderer import page  # noqa: F401 - the fixture: a page of a site serving app/static
from workers.camera import Camera
from workers.streaming.browser import frame_atlas, render_spec
from workers.streaming.demo import demo_rig, demo_scene
from workers.streaming.params import Orbit
from workers.streaming.session import shrunk_rig, source_factor
from workers.streaming.viewpoint import orbit_camera, orbit_frame
from workers.sweep.rig import Rig
from workers.synth import render_views

pytest.importorskip("playwright.sync_api", reason="playwright is not installed (the test extra)")
pytestmark = pytest.mark.skipif(not have_chromium(), reason="Debian's chromium is not installed")


def uneven_rig() -> Rig:
    """Three cameras of different sizes (the smallest decides the factor), odd sizes that round when shrunk."""
    K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    sizes = [(641, 481), (1001, 333), (700, 500)]
    return Rig(tuple(Camera(f"c{i}", K, np.eye(3), np.array([0.3 * i, 0.0, 0.0]), w, h)
                     for i, (w, h) in enumerate(sizes)))


def test_the_browser_sweeps_the_frames_the_server_shrinks_for_every_view_size(page):  # noqa: F811
    rig = uneven_rig()
    sizes = [(w, h) for w in (16, 40, 79, 80, 81, 106, 107, 160, 213, 214, 320, 641, 900)
             for h in (16, 41, 42, 83, 111, 166, 333, 400)]
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


def test_an_option_outside_the_servers_choices_is_refused_naming_them(page):  # noqa: F811
    spec = render_spec(uneven_rig())
    message = page.evaluate("""async ({spec}) => {
      const { BrowserRenderer } = await import("/render/renderer.js");
      const canvas = document.createElement("canvas");
      const r = await BrowserRenderer.create(canvas.getContext("webgl2"), spec);
      try { r.options({ aggregation: "windowed" }); return null; } catch (error) { return error.message; }
      finally { r.dispose(); }
    }""", {"spec": spec})
    assert message == "aggregation must be one of none, window, sgm; got windowed"


def test_a_pass_refuses_what_its_shaders_do_not_declare_or_take(page):  # noqa: F811
    """The pass helper (app/static/render/pass.js) types each uniform from the program: a misspelt name, a value of
    the wrong size, a sampler given the other kind of texture and a uniform the program uses but nobody set all fail
    loudly instead of drawing with stale or zero values."""
    errors = page.evaluate("""async () => {
      const { Pass } = await import("/render/pass.js");
      const { loadShaders } = await import("/render/programs.js");
      const { capabilities, target, texture2d, textureArray } = await import("/render/gl.js");
      const gl = capabilities(document.createElement("canvas")).gl;
      await loadShaders(["fullscreen.vert", "resolve.frag"]);
      const pass = new Pass(gl, "resolve.frag");
      const state = texture2d(gl, "rgba32f", 4, 4);
      const out = target(gl, [texture2d(gl, "rgba32f", 4, 4)]);
      const attempt = (f) => { try { f(); return null; } catch (error) { return error.message; } };
      return {
        misspelt: attempt(() => pass.set({ uSO: 1 })),
        size: attempt(() => pass.set({ uS0: [1, 2] })),
        kind: attempt(() => pass.set({ uStateA: textureArray(gl, "r32f", 4, 4, 2) })),
        unset: attempt(() => { pass.set({ uStateA: state, uS0: 1, uDs: -0.1, uPlanes: 4 }); pass.draw(out); }),
        drawn: attempt(() => { pass.set({ uSubplane: true }); pass.draw(out); }),
        error: gl.getError(),
      };
    }""")
    assert errors == {
        "misspelt": "resolve.frag has no uniform uSO",
        "size": "resolve.frag: uniform uS0 takes 1 number(s) a value, at most 1 values; got [1,2]",
        "kind": "resolve.frag: sampler uStateA takes a 2D texture",
        "unset": "resolve.frag: uniform uSubplane was never set",
        "drawn": None, "error": 0,
    }


def test_frame_sets_and_renders_reuse_their_render_targets(page):  # noqa: F811
    """Render targets are made once per set of attachments: after the first two frame sets and renders (the change
    tracker's arrays and the view's depth alternate between two textures), a third frame set (its silhouettes drawn
    layer by layer) and render of the same size make no framebuffer."""
    rig = demo_rig(4, (96, 72))
    views = render_views(demo_scene(0.25), list(rig.cameras))
    camera = orbit_camera(orbit_frame(rig), Orbit(azimuth=5.0), 50.0, (48, 36))
    made = page.evaluate("""async ({spec, atlas, background, camera}) => {
      const { BrowserRenderer } = await import("/render/renderer.js");
      const { Camera } = await import("/render/camera.js");
      const { capabilities } = await import("/render/gl.js");
      const gl = capabilities(document.createElement("canvas")).gl;
      let made = 0;
      const create = gl.createFramebuffer.bind(gl);
      gl.createFramebuffer = () => { made += 1; return create(); };
      const bitmap = async (b64) => createImageBitmap(await (await fetch(`data:image/png;base64,${b64}`)).blob(),
        { premultiplyAlpha: "none", colorSpaceConversion: "none" });
      const r = await BrowserRenderer.create(gl, spec);
      r.useFactor(1);
      r.frames.setBackgrounds(await bitmap(background), spec.atlas_columns);
      const view = new Camera("virtual", camera.K.flat(), camera.R.flat(), camera.t, camera.width, camera.height);
      const counts = [];
      for (let i = 0; i < 3; i++) {
        r.frames.setFrames(await bitmap(atlas), spec.atlas_columns);
        r.render(view, { aggregation: "sgm", occlusions: "fill", coarse_to_fine: true });
        r.present("regions", false);
        counts.push(made);
      }
      r.dispose();
      return counts;
    }""", {"spec": render_spec(rig), "atlas": png_b64(frame_atlas([v.image for v in views], rig, 1)),
           "background": png_b64(frame_atlas([v.background for v in views], rig, 1)),
           "camera": {"K": camera.K.tolist(), "R": camera.R.tolist(), "t": camera.t.tolist(), "width": camera.width,
                      "height": camera.height}})
    assert made[0] > 0 and made[2] == made[1], f"framebuffers made by the first, two and three rounds: {made}"
