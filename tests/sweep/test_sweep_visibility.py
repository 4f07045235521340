"""Visibility-aware colouring (RenderOptions.visibility, workers.sweep.visibility) on an analytic scene.

A red square at z = 2 m in front of a textured wall at z = 4 m; cameras on the x axis looking along +z,
the virtual camera at the origin. The colour kernel runs on the true depth (a render whose plane choice
is replaced by the analytic one), so every expectation below is geometry, not the depth search.
"""
from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
import pytest

from workers.camera import Camera
from workers.sweep.renderer import RenderOptions, SweepRenderer
from workers.sweep.visibility import surface_zbuffers

W, H, F = 96, 72, 80.0
K = np.array([[F, 0, (W - 1) / 2], [0, F, (H - 1) / 2], [0, 0, 1]])
ZF, ZB, HALF = 2.0, 4.0, 0.3  # foreground square |x|, |y| <= HALF at z = ZF; wall at z = ZB
RED = np.array([0, 0, 255], np.uint8)
MARGIN = 2 * ZF / F  # 2 px of a camera at the square's depth, in metres


def cam(x: float, name: str) -> Camera:
    return Camera(name, K, np.eye(3), np.array([-x, 0.0, 0.0]), W, H)


AWAY = Camera("away", K, np.diag([-1.0, 1.0, -1.0]), np.zeros(3), W, H)  # looks along -z: sees none of the scene
BLANK = np.zeros((H, W, 3), np.uint8)


def wall_colour(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """(..., 3) float64 BGR texture of the wall at world (X, Y)."""
    return np.stack([128 + 90 * np.sin(9 * X + 2 * Y + p) for p in (0.0, 2.0, 4.0)], axis=-1)


def cast(c: Camera, square: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Ray-cast camera ``c``: image (H, W, 3) uint8 and depth (H, W) float64 (m along its axis)."""
    uv = c.pixel_grid().reshape(-1, 2)
    d = np.hstack([c.normalized(uv), np.ones((len(uv), 1))])  # direction with unit z (R = I)
    front = d[:, :2] * ZF + c.center[:2]
    on_square = square & (np.abs(front) <= HALF).all(axis=1)
    back = d[:, :2] * ZB + c.center[:2]
    img = np.where(on_square[:, None], RED.astype(float), wall_colour(back[:, 0], back[:, 1]))
    depth = np.where(on_square, ZF, ZB)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8).reshape(H, W, 3), depth.reshape(H, W)


def hidden(cx: float, P: np.ndarray, margin: float) -> np.ndarray:
    """(n,) bool: the wall points P (n, 3) are behind the square from a camera at (cx, 0, 0), seen at least
    ``margin`` m (at the square's depth) inside its edge; ~hidden(cx, P, -margin): seen at least margin
    outside it (robustly visible)."""
    cross = np.array([cx, 0.0]) + (P[:, :2] - np.array([cx, 0.0])) * ZF / ZB
    return (np.abs(cross) <= HALF - margin).all(axis=1)


def true_depth_render(renderer: SweepRenderer, virtual: Camera, depth: np.ndarray, near: float, far: float):
    """A render of ``virtual`` whose depth is ``depth`` (H, W), each value one of the two planes near, far."""
    res = renderer.render(virtual, planes=2, near=near, far=far, aggregation="none", visual_hull=False)
    index = np.where(depth == near, 0, 1).astype(np.int32)
    return replace(res, depth=depth.astype(np.float32), plane_index=index,
                   plane_offset=np.zeros(depth.shape, np.float32))


@pytest.fixture(scope="module")
def scene():
    """Cameras A (x = -0.4), B (x = 0.4), C (x = 0.6), the virtual camera at 0, its true depth, and the
    wall pixels hidden from A by the square but seen by B and C (away from every edge by 2 px)."""
    cams = {n: cam(x, n) for n, x in (("A", -0.4), ("B", 0.4), ("C", 0.6))}
    images = {n: cast(c)[0] for n, c in cams.items()}
    virtual = cam(0.0, "virtual")
    _, depth = cast(virtual)
    uv = virtual.pixel_grid().reshape(-1, 2)
    P = virtual.backproject(uv, depth.ravel())
    wall = depth.ravel() == ZB
    target = wall & hidden(-0.4, P, MARGIN) & ~hidden(0.4, P, -MARGIN) & ~hidden(0.6, P, -MARGIN)
    return cams, images, virtual, depth, target.reshape(H, W)


def test_hidden_camera_is_excluded_and_gives_the_visible_camera_colour(scene):
    cams, images, virtual, depth, target = scene
    assert target.sum() >= 30  # a strip right of the square, hidden from A
    two = SweepRenderer([cams["A"], cams["B"]], [images["A"], images["B"]])
    first = true_depth_render(two, virtual, depth, ZF, ZB)
    off = two.reshade(first, visibility=False)
    on = two.reshade(first, visibility=True)
    w_off = two.blend_weights(first, visibility=False)
    w_on = two.blend_weights(first, visibility=True)
    # without visibility A's sample (the square's red) is blended in; with it only B takes part
    assert (w_off[target][:, 0] > 0.3).all()
    np.testing.assert_array_equal(w_on[target], np.tile([0.0, 1.0], (target.sum(), 1)).astype(np.float32))
    only_b = SweepRenderer([cams["B"], AWAY], [images["B"], BLANK]).reshade(first, visibility=False)
    np.testing.assert_array_equal(on.image[target], only_b.image[target])
    assert (on.regions[target] == 1).all() and (on.primary[target] == 1).all()
    # known answer: the wall's texture (bilinear sampling of B: within a few levels); the blend is far off
    P = virtual.backproject(virtual.pixel_grid()[target], ZB)
    truth = wall_colour(P[:, 0], P[:, 1])
    assert np.abs(on.image[target] - truth).mean() < 3.0
    assert np.abs(off.image[target] - truth).mean() > 30.0


@pytest.mark.parametrize("method", ["kojima", "kojima_k", "ulr", "nearest"])
def test_hidden_camera_behaves_as_one_that_does_not_see_the_point(scene, method):
    """Where A is hidden, every weighting gives B and C the weights (and the colour) of a rig without A."""
    cams, images, virtual, depth, target = scene
    three = SweepRenderer([cams[n] for n in "ABC"], [images[n] for n in "ABC"])
    without_a = SweepRenderer([cams["B"], cams["C"]], [images["B"], images["C"]])
    first = true_depth_render(three, virtual, depth, ZF, ZB)
    opts = {"method": method, "d_bnd": 0.002, "k": 2}
    w_on = three.blend_weights(first, visibility=True, **opts)
    w_ref = without_a.blend_weights(first, visibility=False, **opts)
    assert (w_on[target][:, 0] == 0).all()
    np.testing.assert_array_equal(w_on[target][:, 1:], w_ref[target])
    np.testing.assert_array_equal(three.reshade(first, visibility=True, **opts).image[target],
                                  without_a.reshade(first, visibility=False, **opts).image[target])
    assert (three.blend_weights(first, visibility=False, **opts)[target][:, 0] > 0).any()


def test_nothing_hidden_gives_the_same_output(scene):
    """A wall alone: no camera is hidden anywhere, so visibility changes no weight and no colour."""
    cams, _, virtual, _, _ = scene
    images = [cast(cams[n], square=False)[0] for n in "AB"]
    two = SweepRenderer([cams["A"], cams["B"]], images)
    first = true_depth_render(two, virtual, np.full((H, W), ZB), ZF, ZB)
    for method in ("kojima", "kojima_k", "ulr", "nearest", "global"):
        off, on = two.reshade(first, method=method, visibility=False), two.reshade(first, method=method, visibility=True)
        np.testing.assert_array_equal(on.image, off.image)
        np.testing.assert_array_equal(on.regions, off.regions)
        np.testing.assert_array_equal(two.blend_weights(first, method=method, visibility=True),
                                      two.blend_weights(first, method=method, visibility=False))


def test_point_hidden_from_every_camera_keeps_all_of_them(scene):
    """A far patch (z = 8 m) inside a near wall (z = 2 m) of the depth map is behind that wall from both
    cameras: the colour falls back to every camera that sees it (no hole, today's blend)."""
    cams, images, virtual, _, _ = scene
    two = SweepRenderer([cams["A"], cams["B"]], [images["A"], images["B"]])
    depth = np.full((H, W), 2.0)
    patch = np.zeros((H, W), bool)
    patch[33:39, 45:51] = True
    depth[patch] = 8.0
    first = true_depth_render(two, virtual, depth, 2.0, 8.0)
    zbuf, zbox = surface_zbuffers(*two.geometry(virtual)[:2], 1.0 / depth, two._sizes, two._imgs.shape[:3])
    for i, c in enumerate((cams["A"], cams["B"])):  # the patch really is behind the wall in both buffers
        p, z = c.project(virtual.backproject(virtual.pixel_grid()[patch], 8.0))
        u, v = np.rint(p).astype(int).T
        assert (zbuf[i, v, u] < 0.5 * z).all()
    w_off = two.blend_weights(first, visibility=False)
    w_on = two.blend_weights(first, visibility=True)
    np.testing.assert_array_equal(w_on[patch], w_off[patch])
    assert (w_on[patch] > 0).all()
    np.testing.assert_array_equal(two.reshade(first, visibility=True).image[patch],
                                  two.reshade(first, visibility=False).image[patch])


def test_a_camera_where_the_view_stands_is_never_hidden(scene):
    """The view at camera A's place: no surface can pass in front of another from there, yet A's z-buffer holds the
    square's pixels in the 2x2 footprints of the wall pixels beside its edges (a neighbour that has not moved against
    them, not an occluder). A keeps every weight it has without visibility; B, 0.8 m away, is still dropped where the
    square hides the wall from it. The wall pixels beside the square's edges have the square's depth among the four
    buffered pixels A samples them from: the nearest-depth test alone dropped A there (what the test guards)."""
    cams, images, _, _, _ = scene
    at_a = cam(-0.4, "virtual")
    _, depth = cast(at_a)
    two = SweepRenderer([cams["A"], cams["B"]], [images["A"], images["B"]])
    first = true_depth_render(two, at_a, depth, ZF, ZB)
    blend = {"method": "kojima_k", "d_bnd": 0.5}  # both cameras weighted wherever they see the point
    w_off = two.blend_weights(first, visibility=False, **blend)
    w_on = two.blend_weights(first, visibility=True, **blend)
    np.testing.assert_array_equal(w_on[..., 0] > 0, w_off[..., 0] > 0)
    assert ((w_off[..., 1] > 0) & (w_on[..., 1] == 0)).sum() >= 30  # B: the wall strip the square hides from it
    Q, B, _ = two.geometry(at_a)
    sizes = np.array([[W, H], [W, H]], np.int64)
    zbuf, _ = surface_zbuffers(Q, B, 1.0 / depth.astype(np.float64), sizes, (2, H, W))
    taps = np.minimum.reduce([zbuf[0, :-1, :-1], zbuf[0, :-1, 1:], zbuf[0, 1:, :-1], zbuf[0, 1:, 1:]])
    nearer = taps * (1.0 + RenderOptions().visibility_tolerance) < ZB  # the visibility test's margin
    beside = (depth[:-1, :-1] == ZB) & nearer & (w_off[:-1, :-1, 0] > 0)  # A sees (x, y) at (x, y)
    assert beside.sum() >= 10


def test_zbuffer_of_a_fronto_parallel_wall():
    """Known answer: the virtual view's wall at z = 4 m, seen by a camera 0.4 m to the right with the same
    orientation, lies at 4 m along its axis over the columns it projects to, -8..87 px (clipped; +1 for the
    2x2 footprint) and every row; the rest of the camera's box holds no surface."""
    virtual, right = cam(0.0, "v"), cam(0.4, "r")
    renderer = SweepRenderer([right, AWAY], [BLANK, BLANK])
    Q, B, _ = renderer.geometry(virtual)
    zbuf, zbox = surface_zbuffers(Q, B, np.full((H, W), 1 / ZB), renderer._sizes, renderer._imgs.shape[:3])
    u0, u1, v0, v1 = zbox[0]
    assert (u0, v0, v1) == (0, 0, H - 1) and 88 <= u1 <= 89  # the corners' span, widened by a pixel for rounding
    np.testing.assert_allclose(zbuf[0, :, :88], ZB, rtol=1e-6)
    assert np.isinf(zbuf[0, :, 89:u1 + 1]).all()
    a0, a1, b0, b1 = zbox[1]  # the camera looking away: the scene is behind it, so nothing is written
    assert np.isinf(zbuf[1, b0:b1 + 1, a0:a1 + 1]).all()
    # nothing lands in an image: an empty box
    _, zbox = surface_zbuffers(Q, B, np.zeros((H, W)), renderer._sizes, renderer._imgs.shape[:3])
    assert zbox[0, 0] > zbox[0, 1] and zbox[0, 2] > zbox[0, 3]


def test_visibility_option_is_exposed():
    from workers.streaming.params import Viewpoint
    from workers.sweep.cli import register

    assert RenderOptions().visibility is RenderOptions.model_fields["visibility"].default
    fields, _ = Viewpoint(visibility=True).render_fields("fast")
    assert RenderOptions(**fields).visibility is True
    p = argparse.ArgumentParser()
    register(p.add_subparsers())
    base = ["render", "--rig", "r", "--images", "i", "--pose", "p", "--out", "o.png"]
    assert p.parse_args(base + ["--visibility", "--visibility-tolerance", "0.1"]).visibility is True
    assert p.parse_args(base + ["--no-visibility"]).visibility is False
    with pytest.raises(ValueError):
        RenderOptions(visibility_tolerance=0.0)
