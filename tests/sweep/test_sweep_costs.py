"""workers.sweep.costs against plain numpy definitions, and aggregation in the renderer on a scene where
choosing each pixel alone fails (a repetitive, partly textureless surface)."""
import numpy as np
import pytest

from workers.camera import Camera
from workers.sweep import costs
from workers.sweep.renderer import RenderOptions, SweepRenderer

from .conftest import FAR, NEAR
from harness.numpy_search import plane_costs as numpy_costs


def _window_sum(a: np.ndarray, r: int) -> np.ndarray:
    """Plain numpy: sum over the (2r+1)^2 window of each (y, x), zeros beyond the border; a (h, w, P)."""
    h, w, _ = a.shape
    pad = np.pad(a.astype(np.float64), ((r, r), (r, r), (0, 0)))
    return sum(pad[dy:dy + h, dx:dx + w] for dy in range(2 * r + 1) for dx in range(2 * r + 1))


def _sgm_numpy(c: np.ndarray, p1: float, p2: float, dirs) -> np.ndarray:
    """Plain numpy/python semi-global aggregation (finite costs), the sum of L_r over ``dirs`` (dy, dx)."""
    h, w, P = c.shape
    total = np.zeros((h, w, P))
    for dy, dx in dirs:
        L = np.zeros((h, w, P))
        ys = range(h) if dy >= 0 else range(h - 1, -1, -1)
        xs = list(range(w)) if dx >= 0 else list(range(w - 1, -1, -1))
        for y in ys:
            for x in xs:
                py, px = y - dy, x - dx
                if not (0 <= py < h and 0 <= px < w):
                    L[y, x] = c[y, x]
                    continue
                prev = L[py, px]
                m = prev.min()
                up = np.r_[prev[1:], np.inf]
                down = np.r_[np.inf, prev[:-1]]
                L[y, x] = c[y, x] + np.minimum.reduce([prev, up + p1, down + p1, np.full(P, m + p2)]) - m
        total += L
    return total


def test_windowed_variance_is_the_vote_weighted_window_mean():
    rng = np.random.default_rng(1)
    ssd = rng.uniform(0, 500, (9, 11, 5)).astype(np.float32)
    votes = rng.integers(0, 4, (9, 11, 5)).astype(np.float32)
    ssd[votes == 0] = 0
    for r in (0, 1, 2):
        got = costs.windowed_variance(ssd, votes, r)
        with np.errstate(divide="ignore", invalid="ignore"):
            want = np.where(votes > 0, _window_sum(ssd, r) / _window_sum(votes, r), np.inf)
        np.testing.assert_allclose(got, want, rtol=1e-5)
        assert np.isinf(got[votes == 0]).all()


def test_windowed_variance_of_known_samples():
    # one plane, 3x3 pixels, 2 cameras each: samples (a, b) per pixel -> ssd = (a - b)^2 / 2 per channel
    a = np.array([[0, 10, 0], [0, 4, 0], [0, 0, 0]], float)
    ssd = ((a**2) / 2 * 3)[..., None].astype(np.float32)  # same deviation in B, G and R
    votes = np.full((3, 3, 1), 2, np.float32)
    got = costs.windowed_variance(ssd, votes, 1)
    # centre: every pixel in the window; variance of (a, 0) per pixel is a^2 / 4 per channel
    assert got[1, 1, 0] == pytest.approx(3 * (100 + 16) / 4 / 9)
    assert got[0, 0, 0] == pytest.approx(3 * (100 + 16) / 4 / 4)  # the corner's window covers 4 pixels


def test_windowed_variance_splits_more_than_opencvs_channel_limit():
    rng = np.random.default_rng(2)
    ssd = rng.uniform(0, 10, (4, 5, costs.CV_MAX_CHANNELS + 3)).astype(np.float32)
    votes = np.ones_like(ssd)
    np.testing.assert_allclose(costs.windowed_variance(ssd, votes, 1), _window_sum(ssd, 1) / _window_sum(votes, 1),
                               rtol=1e-5)


@pytest.mark.parametrize("directions", [4, 8])
def test_semi_global_matches_the_recurrence(directions):
    rng = np.random.default_rng(3)
    c = rng.uniform(0, 20, (6, 7, 5)).astype(np.float32)
    dirs = [(0, 1), (0, -1), (1, 0), (-1, 0)]
    if directions == 8:
        dirs += [(1, 1), (1, -1), (-1, 1), (-1, -1)]
    np.testing.assert_allclose(costs.semi_global(c, 1.5, 6.0, directions), _sgm_numpy(c, 1.5, 6.0, dirs), rtol=1e-5)


def test_semi_global_keeps_non_candidates_out_and_restarts_after_empty_pixels():
    c = np.full((1, 5, 3), 1.0, np.float32)
    c[0, 1, 2] = np.inf
    c[0, 2, :] = np.inf  # no candidate: both paths restart after it
    out = costs.semi_global(c, 1.0, 4.0, 4)
    assert np.isinf(out[0, 1, 2]) and np.isinf(out[0, 2]).all()
    assert np.isfinite(out[0, [0, 3, 4]]).all()


@pytest.mark.parametrize("directions", [4, 8])
def test_semi_global_within_plane_windows_equals_the_whole_volume(directions):
    """A coarse-to-fine level's cost is inf outside each pixel's narrow window: the paths kept to the windows give
    the total over all planes bit for bit (inf outside), also where a window is empty or a neighbour's is disjoint."""
    rng = np.random.default_rng(5)
    h, w, P = 9, 11, 12
    lo = rng.integers(0, P - 3, (h, w)).astype(np.int32)
    hi = (lo + rng.integers(0, 4, (h, w))).astype(np.int32)
    hi[2, 3] = lo[2, 3] - 1  # no candidate at all
    c = rng.uniform(0, 20, (h, w, P)).astype(np.float32)
    j = np.arange(P)[None, None, :]
    c[(j < lo[..., None]) | (j > hi[..., None])] = np.inf
    c[4, 4, lo[4, 4]] = np.inf  # a non-candidate inside a window
    whole = costs.semi_global(c, 1.5, 6.0, directions)
    windowed = costs.semi_global(c, 1.5, 6.0, directions, windows=(lo, hi))
    np.testing.assert_array_equal(windowed, whole)
    assert np.isinf(windowed[2, 3]).all() and np.isfinite(windowed[0, 0, lo[0, 0]])
    with pytest.raises(ValueError, match="windows"):
        costs.semi_global(c, 1.5, 6.0, directions, windows=(lo[:-1], hi[:-1]))


def test_semi_global_rejects_bad_penalties():
    with pytest.raises(ValueError):
        costs.semi_global(np.zeros((2, 2, 2), np.float32), 3.0, 1.0)
    with pytest.raises(ValueError):
        costs.semi_global(np.zeros((2, 2, 2), np.float32), 1.0, 3.0, directions=6)


@pytest.mark.parametrize("vertex", [-0.4, -0.1, 0.0, 0.25, 0.45])
def test_subplane_refinement_finds_a_parabolas_vertex(vertex):
    j = np.arange(9, dtype=float)
    centre = 4 + vertex
    cost = (2.5 * (j - centre) ** 2 + 7.0).astype(np.float32)[None, None, :]
    best, value, offset = costs.winner(cost)
    assert best[0, 0] == 4 and value[0, 0] == cost[0, 0, 4]
    assert best[0, 0] + offset[0, 0] == pytest.approx(centre, abs=1e-5)


def test_winner_ties_ends_and_empty_pixels():
    cost = np.array([[[3.0, 1.0, 1.0, 5.0], [0.5, 2.0, 3.0, 4.0], [np.inf] * 4, [2.0, 2.0, 2.0, 2.0]]], np.float32)
    best, value, offset = costs.winner(cost)
    np.testing.assert_array_equal(best[0], [1, 0, -1, 0])  # ties to the nearer plane
    assert np.isinf(value[0, 2]) and offset[0, 0] == pytest.approx(0.5)  # (3, 1, 1): vertex half-way
    assert offset[0, 1] == 0 and offset[0, 2] == 0 and offset[0, 3] == 0  # first plane; flat


def test_the_cost_volume_is_the_per_plane_variance(capture, between_camera):
    """The renderer's unpruned volume (16-lane sampling) against the numpy definition of each plane's cost."""
    _, rig, views = capture
    cam = between_camera.scaled(0.5)
    r = SweepRenderer(rig, [v.image for v in views])
    s_planes = 1.0 / r.depth_planes(cam, 6, NEAR, FAR)
    Q, B, _ = r.geometry(cam)
    lo = np.zeros((cam.height, cam.width), np.int32)
    hi = np.full_like(lo, 5)
    hi[:, ::3] = 2  # some windows stop early: those planes get no votes
    ssd, votes = r._volume(Q, B, cam.center, s_planes, False, RenderOptions(subpixel_bits=4), lo, hi)
    want = numpy_costs(list(rig.cameras), [v.image for v in views], None, cam, s_planes, 4).transpose(1, 2, 0)
    want[:, ::3, 3:] = np.inf
    got = costs.windowed_variance(ssd, votes, 0)
    np.testing.assert_array_equal(np.isfinite(got), np.isfinite(want))
    ok = np.isfinite(want)
    np.testing.assert_allclose(got[ok], want[ok], rtol=1e-4, atol=1e-3)


def _stripes_rig():
    """Four rectified cameras 0.1 m apart looking at a fronto-parallel wall at 2 m whose texture repeats every
    8 px (in the middle camera) with flat bands between: alone, a pixel matches several planes equally well."""
    w, h, f = 96, 64, 80.0
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])
    xs = np.arange(-0.15, 0.16, 0.1)
    cams = [Camera.from_center(f"c{i}", K, np.eye(3), [x, 0.0, 0.0], w, h) for i, x in enumerate(xs)]
    rng = np.random.default_rng(4)
    u = np.arange(4 * w) / 4.0  # wall texture along X, supersampled
    period = np.where((u % 8) < 3, 200.0, 60.0) + rng.normal(0, 1.5, u.size)
    period[(u > 30) & (u < 50)] = 120.0  # a textureless band
    images = []
    for x in xs:
        X = ((np.arange(w) - (w - 1) / 2) / f) * 2.0 + x  # wall X seen by each column at depth 2
        tex = np.interp(X, (u - (w - 1) / 2) / f * 2.0, period)
        row = np.clip(tex + rng.normal(0, 2.0, w), 0, 255)
        images.append(np.repeat(np.repeat(row[None, :, None], h, 0), 3, 2).astype(np.uint8))
    virtual = Camera.from_center("v", K, np.eye(3), [0.05, 0.0, 0.0], w, h)
    return cams, images, virtual


def test_aggregation_beats_winner_take_all_on_a_repetitive_textureless_wall():
    cams, images, virtual = _stripes_rig()
    r = SweepRenderer(cams, images)
    kw = dict(planes=40, near=1.2, far=4.0)
    errs = {}
    for agg in ("none", "window", "sgm"):
        out = r.render(virtual, aggregation=agg, **kw)
        inner = np.isfinite(out.depth)
        inner[:, :12] = inner[:, -12:] = False  # columns not all cameras see
        errs[agg] = np.mean(np.abs(out.depth[inner] - 2.0) < 0.1)
    assert errs["none"] < 0.9
    assert errs["window"] > errs["none"] + 0.05
    assert errs["sgm"] > 0.95 and errs["sgm"] >= errs["window"]


def test_options_pair_aggregation_with_the_variance_cost():
    assert RenderOptions(consistency="truncated").aggregation == "none"  # the default follows the cost
    with pytest.raises(ValueError):
        RenderOptions(consistency="truncated", aggregation="sgm")
    with pytest.raises(ValueError):
        RenderOptions(sgm_p1=9.0, sgm_p2=3.0)
