"""The compiled sweep against plain numpy evaluations of the same definitions (packed fixed-point
sampling, pruning, visual-hull culling and its bounding-box pre-cut, window refinement)."""
from dataclasses import replace

import numpy as np
import pytest

from workers.camera import Camera
from workers.sweep import kernels
from workers.sweep.lanes import LANES
from workers.sweep.renderer import RenderOptions, SweepRenderer
from workers.sweep.silhouette import silhouette_box, silhouette_from_background

from .conftest import FAR, NEAR
from harness.numpy_search import best_plane as _best
from harness.numpy_search import plane_costs as _numpy_costs


@pytest.fixture(scope="module")
def small(capture, between_camera):
    _, rig, views = capture
    return rig, views, between_camera.scaled(0.5)


@pytest.mark.parametrize("bits", [3, 6])
@pytest.mark.parametrize("consistency", ["variance", "truncated"])
def test_packed_fixed_point_cost_of_each_plane_is_exact(small, bits, consistency):
    rig, views, cam = small
    r = SweepRenderer(rig, [v.image for v in views])
    opt = RenderOptions(subpixel_bits=bits, consistency=consistency, truncation=20.0)
    s_planes = 1.0 / r.depth_planes(cam, 6, NEAR, FAR)
    want = _numpy_costs(list(rig.cameras), [v.image for v in views], None, cam, s_planes, bits,
                        trunc2=400.0 if consistency == "truncated" else 0.0)
    Q, B, _ = r.geometry(cam)
    for j in range(len(s_planes)):
        lo = np.full((cam.height, cam.width), j, np.int32)  # a window of one plane: its own cost comes back
        best, cost = r.sweep(Q, B, cam.center, s_planes, False, opt, lo, lo.copy())
        finite = np.isfinite(want[j])
        np.testing.assert_array_equal(best, np.where(finite, j, -1))
        np.testing.assert_allclose(cost[finite], want[j][finite], rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("hull", [False, True])
def test_pruned_sweep_equals_exhaustive_search(small, hull):
    rig, views, cam = small
    images = [v.image for v in views]
    r = SweepRenderer(rig, images, backgrounds=[v.background for v in views]) if hull else SweepRenderer(rig, images)
    out = r.render(cam, planes=24, near=NEAR, far=FAR, subpixel_bits=4, aggregation="none")  # the pruned search
    sils = r.silhouettes() if hull else None
    want = _best(_numpy_costs(list(rig.cameras), images, sils, cam, 1.0 / out.planes, 4))
    assert (out.plane_index == want).mean() > 0.999  # rounding at exact .5 positions may differ
    if hull:
        assert (want < 0).mean() > 0.3  # the hull did cull
        assert ((out.plane_index >= 0) == (want >= 0)).mean() > 0.999


def test_hull_windows_keep_every_plane_inside_all_silhouettes():
    rng = np.random.default_rng(5)
    K = np.array([[120.0, 0, 63.5], [0, 120.0, 47.5], [0, 0, 1]])
    cams = [Camera.look_at(f"c{i}", [3 * np.sin(a), -3 * np.cos(a), 1.0], [0, 0, 0.3], fov_deg=55, width=128,
                           height=96) for i, a in enumerate(np.radians([-50, -20, 15, 45]))]
    cams = [Camera(c.name, K, c.R, c.t, 128, 96) for c in cams]
    sils = []
    for _ in cams:  # random blobs
        m = np.zeros((96, 128), bool)
        for _ in range(3):
            cx, cy, rad = rng.uniform(20, 108), rng.uniform(15, 80), rng.uniform(6, 20)
            yy, xx = np.mgrid[:96, :128]
            m |= (xx - cx) ** 2 + (yy - cy) ** 2 < rad**2
        sils.append(m)
    r = SweepRenderer(cams, [rng.integers(0, 255, (96, 128, 3), dtype=np.uint8) for _ in cams], silhouettes=sils,
                      hull_dilate=0)
    virtual = Camera.look_at("v", [0.4, -3.2, 1.1], [0, 0, 0.3], fov_deg=50, width=96, height=72)
    s_planes = 1.0 / r.depth_planes(virtual, 40, 1.5, 6.0)
    Q, B, _ = r.geometry(virtual)
    lo, hi = r.search_window(Q, B, 72, 96, s_planes, True)
    inside = np.isfinite(_numpy_costs(cams, [np.zeros((96, 128, 3), np.uint8)] * 4, sils, virtual, s_planes, 6,
                                      min_views=1))
    j = np.arange(len(s_planes))[:, None, None]
    assert not (inside & ((j < lo) | (j > hi))).any()
    kept = np.where(hi >= lo, hi - lo + 1, 0).sum() / (len(s_planes) * lo.size)
    assert kept < 0.7 and (hi < lo).mean() > 0.2  # and it does cut: whole rays and parts of others


def test_search_step_is_one_64th_px_for_bits_zero_and_above_six(small):
    rig, views, cam = small
    r = SweepRenderer(rig, [v.image for v in views])
    kw = dict(planes=16, near=NEAR, far=FAR)
    fine = r.render(cam, subpixel_bits=kernels.MAX_BITS, **kw)
    for bits in (0, 8):
        np.testing.assert_array_equal(r.render(cam, subpixel_bits=bits, **kw).cost, fine.cost)


def test_refine_windows_match_their_definition():
    rng = np.random.default_rng(2)
    coarse = rng.integers(-1, 30, (13, 17)).astype(np.int32)
    coarse[4:9, 5:12] = -1
    h, w = 26, 33
    lo = np.empty((h, w), np.int32)
    hi = np.empty((h, w), np.int32)
    kernels.refine_windows(coarse, h, w, 1, 2, 30, lo, hi)
    for y in range(h):
        for x in range(w):
            cy, cx = min(y // 2, 12), min(x // 2, 16)
            nb = coarse[max(cy - 1, 0):cy + 2, max(cx - 1, 0):cx + 2]
            valid = nb[nb >= 0]
            if valid.size == 0:
                assert lo[y, x] > hi[y, x]
            else:
                assert (lo[y, x], hi[y, x]) == (max(valid.min() - 2, 0), min(valid.max() + 2, 29))


@pytest.mark.parametrize("threshold", [-1.0, 0.0, 19.5, 20.0, 254.0, 254.9, 255.0])
def test_silhouette_threshold_is_on_the_largest_channel_difference(threshold):
    rng = np.random.default_rng(1)
    img = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    bg = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    want = np.abs(img.astype(int) - bg.astype(int)).max(axis=2) > threshold
    np.testing.assert_array_equal(silhouette_from_background(img, bg, threshold, clean_px=0), want)


def test_silhouette_box_is_widened_by_half_a_pixel():
    m = np.zeros((30, 40), bool)
    assert silhouette_box(m)[0] > silhouette_box(m)[1]
    m[5:9, 12:20] = True
    m[22, 3] = True
    assert silhouette_box(m) == (2.5, 19.5, 4.5, 22.5)


def test_pruning_keeps_a_nearer_plane_that_ties_the_seed_after_rounding():
    """Seven cameras sample 0, 0, 0, 0, 0, 0, 3 at plane 0 and one level more at plane 1: equal variances,
    54/49 levels^2, which float64 rounds so that cost * 49 falls below the exact SSD. The last pixel tries
    plane 1 first (the choice of the pixel left of its group of lanes); the full search keeps plane 0 (ties
    go to the nearer plane)."""
    n_cam, W, H, bits = 7, 4, 4, 1
    imgs = np.zeros((n_cam, H, W, 3), np.uint8)
    imgs[:, 1, 1, 0] = [0, 0, 0, 0, 0, 0, 3]  # plane 0 (s = 0) projects to pixel (1, 1) in every camera
    imgs[:, 2, 2, 0] = [1, 1, 1, 1, 1, 1, 4]  # plane 1 (s = 1) to pixel (2, 2)
    sizes = np.tile([W, H], (n_cam, 1)).astype(np.int64)
    pix = np.zeros((n_cam, H + 1, W + 1), np.uint64)
    kernels.pack_images(imgs, sizes, pix)
    camf = np.zeros((n_cam, kernels.CAM_F))
    camf[:, [2, 5, 8]] = 1.0  # a_i(x, y) = (1, 1, 1) at every pixel
    camf[:, [9, 10]] = 1.0  # B_i = (1, 1, 0): the point of plane s at (1 + s, 1 + s)
    cami = np.array([((W - 1) << bits, (H - 1) << bits, i * (H + 1) * (W + 1), W + 1, i * H * W, W, 0, 0)
                     for i in range(n_cam)], np.int64)
    w = LANES + 1
    lo = np.ones((1, w), np.int32)  # the first group of lanes may only take plane 1, the last pixel either
    lo[0, -1] = 0
    hi = np.ones((1, w), np.int32)
    best = np.empty((1, w), np.int32)
    cost = np.empty((1, w), np.float32)
    kernels.sweep_depth(camf.ravel(), cami.ravel(), pix.ravel(), np.ones(n_cam * H * W, np.uint8), False, 2, 0.0,
                        bits, np.array([0.0, 1.0]), lo, hi, np.zeros(1, np.int64), 16, best, cost)
    np.testing.assert_array_equal(best[0], [1] * LANES + [0])
    np.testing.assert_allclose(cost, np.full((1, w), 54 / 49), rtol=1e-6)


@pytest.mark.parametrize("hull", [False, True])
def test_search_honours_each_pixels_window_at_any_width(small, hull):
    """Per-pixel plane windows (coarse-to-fine gives such) and a view width that is no multiple of the
    pixels swept together: every pixel gets the best plane of its own window, -1 for an empty one."""
    rig, views, cam = small
    K = cam.K.copy()
    K[:2, 2] -= [(cam.width - 45) / 2, (cam.height - 37) / 2]  # the centre of the view
    cam = replace(cam, K=K, width=45, height=37)
    images = [v.image for v in views]
    r = SweepRenderer(rig, images, backgrounds=[v.background for v in views]) if hull else SweepRenderer(rig, images)
    P = 20
    s_planes = 1.0 / r.depth_planes(cam, P, NEAR, FAR)
    rng = np.random.default_rng(7)
    lo = rng.integers(0, P, (cam.height, cam.width)).astype(np.int32)
    hi = np.minimum(lo + rng.integers(-1, 8, lo.shape), P - 1).astype(np.int32)  # lo > hi: an empty window
    Q, B, _ = r.geometry(cam)
    best, _ = r.sweep(Q, B, cam.center, s_planes, hull, RenderOptions(subpixel_bits=4), lo, hi)
    costs = _numpy_costs(list(rig.cameras), images, r.silhouettes() if hull else None, cam, s_planes, 4)
    j = np.arange(P)[:, None, None]
    costs[(j < lo) | (j > hi)] = np.inf
    assert (best == _best(costs)).mean() > 0.999  # rounding at exact .5 positions may differ
    assert (best[hi < lo] == -1).all() and (best >= 0).mean() > (0.1 if hull else 0.5)  # the hull culls many
