"""The browser renderer (app/static/render, WebGL2) against the server's renderer (workers/sweep) on the same
frames and viewpoint: headless Chromium with SwiftShader, so it runs without a GPU.

Why a pixel may differ at all: the browser computes in float32 where the server uses float64 and exact integer
sums, so a projected position within about 1e-4 px of a 1/128 px rounding boundary can round to the neighbouring
1/64 px sample, and a cost within float32 rounding of another plane's can pick that plane instead; the colour
pass then samples at float32 positions (a level at most on a few pixels)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from harness.browser import chromium, have_chromium, render_in_browser, static_site
from workers.camera import Camera
from workers.common.datasets import dataset
from workers.common.imagemetrics import psnr
from workers.streaming.browser import frame_atlas, render_spec
from workers.streaming.demo import demo_rig, demo_scene
from workers.streaming.params import Orbit
from workers.streaming.session import _composed, shrunk_images, shrunk_rig, source_factor
from workers.streaming.viewpoint import orbit_camera, orbit_frame
from workers.sweep.renderer import RenderOptions, SweepRenderer
from workers.sweep.rig import Rig
from workers.sweep.rig_io import rectified_rig
from workers.synth import render_views

pytest.importorskip("playwright.sync_api", reason="playwright is not installed (the test extra)")
pytestmark = pytest.mark.skipif(not have_chromium(), reason="Debian's chromium is not installed")

VIEW = (96, 72)
MIN_PSNR = 35.0
MIN_SAME_PLANE = 0.95


@pytest.fixture(scope="module")
def studio():
    """The demo rig (10 cameras, small) with one frame set of the demo studio and its empty-scene images."""
    rig = demo_rig(10, (192, 144))
    views = render_views(demo_scene(0.25), list(rig.cameras))
    return rig, [v.image for v in views], [v.background for v in views]


@pytest.fixture(scope="module")
def page():
    with static_site() as base, chromium() as browser:
        p = browser.new_page()
        p.goto(f"{base}/render/renderer.js")  # any page of the site: the modules import from its origin
        yield p


def server_render(rig: Rig, frames, backgrounds, camera: Camera, **options):
    """The server's render (RenderResult) of one view from frames shrunk as the browser gets them."""
    small = shrunk_rig(rig, source_factor(rig, camera.width, camera.height))
    server = SweepRenderer(small, shrunk_images(frames, small), device="cpu",
                           backgrounds=None if backgrounds is None else shrunk_images(backgrounds, small))
    return server.render(camera, RenderOptions(**options))


def both(page, rig: Rig, frames, backgrounds, camera: Camera, overlay: str = "none", **options):
    """The server's render (RenderResult) and the browser's (render_in_browser's dict) of one view."""
    factor = source_factor(rig, camera.width, camera.height)
    result = server_render(rig, frames, backgrounds, camera, **options)
    browser = render_in_browser(page, render_spec(rig), frame_atlas(frames, rig, factor),
                                None if backgrounds is None else frame_atlas(backgrounds, rig, factor), camera,
                                factor, options, overlay)
    return result, browser


def assert_same_view(result, browser, picture=None):
    assert (result.plane_index >= 0).mean() > 0.3  # a view with a surface to compare (a blank one would pass)
    image = result.image if picture is None else picture
    assert psnr(image, browser["image"]) >= MIN_PSNR
    same = browser["depth"][:, :, 1].astype(np.int32) == result.plane_index
    assert same.mean() >= MIN_SAME_PLANE, f"the same plane on {same.mean():.1%} of the pixels"
    # the chosen plane's cost (the aggregated one: the semi-global total, the windowed variance) is the server's
    # up to float32 rounding, except where a camera's sample moved to the neighbouring 1/64 px (under 1 % of the
    # pixels on the studio; a penalty off by one level in the semi-global paths moves 5 %)
    same &= np.isfinite(result.cost)
    close = np.isclose(browser["depth"][:, :, 3][same], result.cost[same], rtol=1e-3, atol=1e-2)
    assert close.mean() >= 0.98, f"the same cost on {close.mean():.1%} of the pixels"


@pytest.mark.parametrize("azimuth, options", [
    (10.0, {}),  # the server's defaults: kojima, automatic D_bnd, window aggregation, sub-plane, hull
    (-25.0, {"method": "kojima_k"}),
    (30.0, {"method": "ulr", "k": 3}),
    (0.0, {"method": "nearest", "planes": 32}),
    (-40.0, {"method": "global"}),
    (20.0, {"method": "kojima", "d_bnd": 0.02}),
    (-10.0, {"coarse_to_fine": True}),  # the viewer's default: the coarse level aggregated, the fine one per pixel
    (15.0, {"aggregation": "none"}),
    (5.0, {"visual_hull": False, "planes": 24, "near": 1.5, "far": 4.0}),
    (-20.0, {"aggregation": "sgm"}),  # semi-global, 8 directions
    (25.0, {"aggregation": "sgm", "sgm_directions": 4, "planes": 30, "sgm_p1": 4.0, "sgm_p2": 20.0, "window": 1}),
    (8.0, {"aggregation": "sgm", "coarse_to_fine": True, "visual_hull": False}),
])
def test_browser_view_equals_the_servers(page, studio, azimuth, options):
    rig, frames, backgrounds = studio
    camera = orbit_camera(orbit_frame(rig), Orbit(azimuth=azimuth), 50.0, VIEW)
    result, browser = both(page, rig, frames, backgrounds, camera, **options)
    assert_same_view(result, browser)
    if result.d_bnd is None:
        assert browser["info"]["d_bnd"] is None
    else:
        assert browser["info"]["d_bnd"] == pytest.approx(result.d_bnd, rel=1e-5)
    assert browser["info"]["depth_range"] == pytest.approx([result.planes.min(), result.planes.max()], rel=1e-9)
    assert browser["info"]["visual_hull"] == result.visual_hull


@pytest.mark.parametrize("overlay", ["regions", "depth"])
def test_overlays_equal_the_servers(page, studio, overlay):
    rig, frames, backgrounds = studio
    camera = orbit_camera(orbit_frame(rig), Orbit(azimuth=12.0), 50.0, VIEW)
    result, browser = both(page, rig, frames, backgrounds, camera, overlay, method="kojima_k")
    assert_same_view(result, browser, _composed(result, overlay))


def test_distorted_cameras_are_undistorted_before_the_browser_sees_them(page, studio):
    rig, frames, backgrounds = studio
    dist = np.array([-0.12, 0.03, 0.0, 0.0, 0.0])
    distorted = Rig(tuple(Camera(c.name, c.K, c.R, c.t, c.width, c.height, dist) for c in rig.cameras))
    camera = orbit_camera(orbit_frame(rig), Orbit(azimuth=-5.0), 50.0, VIEW)
    result, browser = both(page, distorted, frames, backgrounds, camera)
    assert_same_view(result, browser)


@pytest.mark.parametrize("block", [1, 32, 200])
def test_semi_global_paths_do_not_depend_on_the_block_size(page, studio, block):
    """A path advanced 1 line a draw, 32 (a GPU's block) or all at once chooses what the default block chooses."""
    rig, frames, backgrounds = studio
    camera = orbit_camera(orbit_frame(rig), Orbit(azimuth=-15.0), 50.0, VIEW)
    args = (page, render_spec(rig), frame_atlas(frames, rig, 2), frame_atlas(backgrounds, rig, 2), camera, 2,
            {"aggregation": "sgm"})
    default, other = render_in_browser(*args), render_in_browser(*args, sgm_block=block)
    assert (default["depth"][:, :, 1] >= 0).mean() > 0.3
    np.testing.assert_array_equal(other["depth"], default["depth"])


def assert_same_fill(result, browser):
    """The pixels the cross-view check rejected and filled: the browser marks them with a NaN cost, as the server.
    (Identical on the studio's views; a camera pixel's winner compares costs of different virtual pixels, which a
    float32 rounding apart from the server's can swap.)"""
    assert result.filled.any(), "the check rejected nothing here: the comparison would not test the fill"
    filled = np.isnan(browser["depth"][:, :, 3])
    assert (filled == result.filled).mean() >= 0.99, f"the same pixels filled on {(filled == result.filled).mean():.1%}"


@pytest.mark.parametrize("azimuth, options", [
    (-20.0, {"aggregation": "sgm", "occlusions": "fill"}),
    (12.0, {"occlusions": "fill", "method": "kojima_k"}),  # the window's variance kept as a volume
    (-8.0, {"occlusions": "fill", "coarse_to_fine": True}),  # the viewer's: the fine level's windows kept as a volume
    (18.0, {"aggregation": "sgm", "occlusions": "fill", "coarse_to_fine": True, "method": "ulr"}),
])
def test_the_occlusion_fill_equals_the_servers(page, studio, azimuth, options):
    """The cross-view check, the background fill and the visibility-aware colour that follows it (on with the fill)."""
    rig, frames, backgrounds = studio
    camera = orbit_camera(orbit_frame(rig), Orbit(azimuth=azimuth), 50.0, VIEW)
    result, browser = both(page, rig, frames, backgrounds, camera, **options)
    assert_same_view(result, browser)
    assert_same_fill(result, browser)


def test_a_view_on_a_camera_keeps_that_camera_at_the_filled_pixels_as_the_server(page):
    """Four cameras 30 degrees apart, the view at the place of the one at azimuth 15: nothing has moved against
    anything from that camera, so no nearer surface in its z-buffer hides a point from it (workers/sweep/kernels.py
    unhidden, MIN_OCCLUDER_PARALLAX_PX) and the filled pixels keep its colour, in the browser as on the server
    (before the rule, it was dropped at 1.4 % of the pixels; a browser without it scores 28.4 dB here). The costs
    are not compared: on a camera its samples fall on whole pixels, where float32 rounding takes the neighbouring
    1/64 px sample on about a tenth of the pixels."""
    rig = demo_rig(4, (192, 144))
    views = render_views(demo_scene(0.25), list(rig.cameras))
    frames, backgrounds = [v.image for v in views], [v.background for v in views]
    camera = orbit_camera(orbit_frame(rig), Orbit(azimuth=15.0), 50.0, VIEW)
    own = int(np.argmin([np.linalg.norm(c.center - camera.center) for c in rig.cameras]))
    assert np.linalg.norm(rig.cameras[own].center - camera.center) < 1e-6
    result, browser = both(page, rig, frames, backgrounds, camera, aggregation="sgm", occlusions="fill",
                           coarse_to_fine=True)
    assert_same_fill(result, browser)
    same = result.filled & (browser["depth"][:, :, 1].astype(np.int32) == result.plane_index)
    assert same.sum() >= 100
    assert psnr(result.image, browser["image"], same) >= MIN_PSNR


def test_visibility_aware_colour_equals_the_servers(page, studio):
    """Visibility alone (the searched depth kept): the browser's picture is the server's with visibility, not the
    server's without (where the two differ)."""
    rig, frames, backgrounds = studio
    camera = orbit_camera(orbit_frame(rig), Orbit(azimuth=-30.0), 50.0, VIEW)
    result, browser = both(page, rig, frames, backgrounds, camera, visibility=True)
    assert_same_view(result, browser)
    blind = server_render(rig, frames, backgrounds, camera, visibility=False).image
    differs = np.any(result.image != blind, axis=2)
    assert differs.mean() > 0.005, "visibility changes nothing here: the comparison would not test it"
    own = np.abs(browser["image"].astype(int) - result.image)[differs].mean()
    other = np.abs(browser["image"].astype(int) - blind)[differs].mean()
    assert own < 0.25 * other, f"where visibility matters the browser is {own:.1f} levels from it, {other:.1f} from without"


def test_with_the_fill_visibility_applies_at_the_filled_pixels_only_as_on_the_server(page, studio):
    """The best quality level's rule (visibility None with the fill): the browser tests the filled pixels only, as the
    server does, not every pixel (compared at a 3 % margin, where testing every pixel changes many more)."""
    rig, frames, backgrounds = studio
    camera = orbit_camera(orbit_frame(rig), Orbit(azimuth=-13.0), 50.0, VIEW)
    options = {"aggregation": "sgm", "occlusions": "fill", "coarse_to_fine": True, "visibility_tolerance": 0.03}
    result, browser = both(page, rig, frames, backgrounds, camera, **options)
    assert_same_view(result, browser)
    everywhere = server_render(rig, frames, backgrounds, camera, **options, visibility=True).image
    differs = np.any(result.image != everywhere, axis=2)
    assert differs.mean() > 0.005, "the two rules colour alike here: the comparison would not test them"
    own = np.abs(browser["image"].astype(int) - result.image)[differs].mean()
    other = np.abs(browser["image"].astype(int) - everywhere)[differs].mean()
    assert own < 0.25 * other, f"where the rules differ the browser is {own:.1f} levels from its own, {other:.1f} from the other"


@pytest.mark.parametrize("occlusions", ["keep", "fill"])
def test_a_view_drawn_on_the_next_frame_set_keeps_its_depth_where_nothing_moved_as_the_server(page, occlusions):
    """The demo's ball moves between two frame sets and nothing else does: the server's render with the previous one
    (held where still) and the browser's drawn with ``hold`` on the same two sets are the same view."""
    rig = demo_rig(10, (192, 144))
    camera = orbit_camera(orbit_frame(rig), Orbit(azimuth=-13.0), 50.0, VIEW)
    sets = [render_views(demo_scene(p), list(rig.cameras)) for p in (0.0, 1 / 12)]
    frames = [[v.image for v in views] for views in sets]
    backgrounds = [v.background for v in sets[0]]
    options = {"planes": 48, "coarse_to_fine": True, "aggregation": "sgm", "occlusions": occlusions}
    factor = source_factor(rig, camera.width, camera.height)
    small = shrunk_rig(rig, factor)
    server = SweepRenderer(small, shrunk_images(frames[0], small), device="cpu",
                           backgrounds=shrunk_images(backgrounds, small))
    first = server.render(camera, RenderOptions(**options))
    server.set_frames(shrunk_images(frames[1], small))
    searched = server.render(camera, RenderOptions(**options))
    kept = server.render(camera, RenderOptions(**options), previous=first)
    assert kept.held.mean() > 0.3 and (kept.plane_index != searched.plane_index).any()  # the hold changes the view
    browser = render_in_browser(page, render_spec(rig), frame_atlas(frames[0], rig, factor), frame_atlas(
        backgrounds, rig, factor), camera, factor, options, later=(frame_atlas(frames[1], rig, factor),))
    assert browser["info"]["held"]
    assert_same_view(kept, browser)
    differ = kept.plane_index != searched.plane_index  # where holding made the difference: the browser held too
    assert (browser["depth"][:, :, 1][differ].astype(np.int32) == kept.plane_index[differ]).mean() > 0.8
    assert browser["info"]["d_bnd"] == pytest.approx(kept.d_bnd, rel=1e-5)


def test_options_the_browser_does_not_render_are_refused(page, studio):
    rig, frames, backgrounds = studio
    camera = orbit_camera(orbit_frame(rig), Orbit(), 50.0, VIEW)
    args = (page, render_spec(rig), frame_atlas(frames, rig, 2), frame_atlas(backgrounds, rig, 2), camera, 2)
    with pytest.raises(Exception, match="the truncated cost runs on the server"):
        render_in_browser(*args, {"aggregation": "none", "consistency": "truncated"})
    with pytest.raises(Exception, match="occlusions 'fill' checks the planes on a cost volume"):  # as the server says
        render_in_browser(*args, {"aggregation": "none", "occlusions": "fill"})
    big = orbit_camera(orbit_frame(rig), Orbit(), 50.0, (640, 480))  # 5 volumes of 128 planes: 786 MB
    with pytest.raises(Exception, match="needs 786 MB of GPU memory"):
        render_in_browser(page, render_spec(rig), frame_atlas(frames, rig, 1), frame_atlas(backgrounds, rig, 1), big,
                          1, {"aggregation": "sgm", "planes": 128})


TEDDY = dataset("multiview", "teddy")


@pytest.mark.data
@pytest.mark.skipif(TEDDY is None, reason="Middlebury Teddy not in $SWEEPCAST_DATA")
@pytest.mark.parametrize("sources, aggregation, occlusions", [
    ([2, 6], "window", "keep"), ([0, 1, 2, 3, 5, 6, 7, 8], "window", "keep"), ([2, 6], "sgm", "keep"),
    ([2, 6], "sgm", "fill"),
])
def test_a_middlebury_leave_one_out_view_equals_the_servers(page, sources, aggregation, occlusions):
    """Teddy's view 4 held out, synthesised from two and from all eight others at half size (real photographs: no
    backgrounds, no hull), the depth range from the ground-truth disparity as the benchmark takes it."""
    images = {k: cv2.imread(str(TEDDY / f"im{k}.png")) for k in [*sources, 4]}
    h, w = images[4].shape[:2]
    views = sorted([*sources, 4])
    full = rectified_rig([f"im{k}.png" for k in views], w, h, positions=views)
    rig = Rig(tuple(c for c, k in zip(full.cameras, views) if k != 4))
    virtual = full.cameras[views.index(4)].scaled(0.5)
    # quarter pixels, over the 4 view spacings between im2 and im6: per view spacing (the rig's unit baseline)
    disparities = cv2.imread(str(TEDDY / "disp2.pgm"), cv2.IMREAD_UNCHANGED).astype(np.float64) / 4.0 / 4.0
    lo, hi = np.percentile(disparities[disparities > 0], [0.5, 99.5])
    result, browser = both(page, rig, [images[k] for k in sources], None, virtual, near=w / (hi * 1.1),
                           far=w / (lo * 0.9), aggregation=aggregation, occlusions=occlusions)
    assert_same_view(result, browser)
    if occlusions == "fill":
        assert_same_fill(result, browser)
    assert browser["info"]["coverage"] > 0.8  # two views leave the frame edge unseen
