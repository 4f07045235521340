"""The occlusion fill and the visibility rule on a scene with a textureless occluder (workers.synth.occluder_scene):
a flat red box before a colour-noise wall on a checker floor, five cameras on a 40-degree arc, the view held out
between two of them (the best quality level's options: semi-global, coarse-to-fine, the fill)."""
from __future__ import annotations

import numpy as np
import pytest

from workers.common.imagemetrics import psnr
from workers.streaming.quality import LEVELS
from workers.sweep.renderer import RenderOptions, SweepRenderer
from workers.synth import arc_camera, default_arc_rig, occluder_scene, render_views

W, H = 160, 120
BOX = 2  # the box's index in occluder_scene().objects


@pytest.fixture(scope="module")
def occluder():
    scene = occluder_scene()
    cams = default_arc_rig(5, arc_deg=40.0, width=W, height=H)
    virtual = arc_camera(5.0, width=W, height=H, name="virtual")
    views = render_views(scene, cams, with_background=False)
    truth = render_views(scene, [virtual], with_background=False)[0]
    renderer = SweepRenderer(cams, [v.image for v in views], device="cpu")
    options = {"planes": 48, "near": 1.5, "far": 4.5, "visual_hull": False, "coarse_to_fine": True}
    keep = renderer.render(virtual, RenderOptions(**options, **LEVELS["fast"]))
    fill = renderer.render(virtual, RenderOptions(**options, **LEVELS["best"]))
    return renderer, truth, keep, fill


def band(depth: np.ndarray, px: int = 2) -> np.ndarray:
    """Pixels within ``px`` of a depth step of more than 5 % (the occluding edges)."""
    import cv2

    z = np.where(np.isfinite(depth), depth, 1e3)
    step = np.zeros(z.shape, bool)
    step[:, 1:] |= np.abs(np.log(z[:, 1:] / z[:, :-1])) > 0.05
    step[1:] |= np.abs(np.log(z[1:] / z[:-1])) > 0.05
    return cv2.dilate(step.astype(np.uint8), np.ones((2 * px + 1, 2 * px + 1), np.uint8)).astype(bool)


def test_the_check_does_not_reject_the_textureless_occluder(occluder):
    """Every plane through the flat box matches about equally in its middle; the cross-view check confirms it all
    the same (its depth is not replaced by the wall's behind), while it rejects and fills strips beside it."""
    _, truth, _, fill = occluder
    import cv2

    inside = cv2.erode((truth.object_id == BOX).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert inside.sum() > 500
    assert fill.filled[inside].mean() < 0.01
    assert (np.abs(fill.depth - truth.depth) < 0.05 * truth.depth)[inside].mean() > 0.9
    assert fill.filled.sum() > 50


def test_the_fill_puts_the_half_occluded_strips_on_the_background_and_mends_the_edges(occluder):
    """The filled pixels (the strips beside the box one camera does not see) move to about the true depth where
    keeping left them wrong, and the picture in the band around the occluding edges is better than keeping's (the
    smear of the box's colour over the wall and floor is gone); the whole picture stays within a fraction of a dB
    of keeping's here (where the strips' colour comes from cameras far round, it is no better than the spill's)."""
    _, truth, keep, fill = occluder
    f = fill.filled
    rel = lambda res: np.median(np.abs(res.depth - truth.depth)[f] / truth.depth[f])  # noqa: E731
    assert rel(fill) < 0.6 * rel(keep)
    scored = np.isfinite(keep.depth) & np.isfinite(fill.depth)
    edges = scored & band(truth.depth)
    assert psnr(fill.image, truth.image, edges) > psnr(keep.image, truth.image, edges)
    assert psnr(fill.image, truth.image, scored) > psnr(keep.image, truth.image, scored) - 0.5


def test_visibility_applies_at_the_filled_pixels_only(occluder):
    """The default rule (visibility None with the fill): the picture outside the filled pixels is the one without
    visibility, pixel for pixel; at them it is the one with visibility; the old rule (every pixel, at a 3 % margin)
    also changes the confirmed pixels, and for the worse."""
    renderer, truth, _, fill = occluder
    f = fill.filled
    blind = renderer.reshade(fill, visibility=False).image
    everywhere = renderer.reshade(fill, visibility=True).image
    np.testing.assert_array_equal(fill.image[~f], blind[~f])
    np.testing.assert_array_equal(fill.image[f], everywhere[f])
    old = renderer.reshade(fill, visibility=True, visibility_tolerance=0.03).image
    assert np.any(old[~f] != blind[~f])
    scored = np.isfinite(fill.depth) & ~f
    assert psnr(old, truth.image, scored) < psnr(fill.image, truth.image, scored)
