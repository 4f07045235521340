"""The five weightings on constructed angle cases (eqs. 1-6, the k-camera eq. (6k) and the ULR formula)."""
import numpy as np
import pytest

from workers.sweep.weighting import (
    global_camera,
    kojima_k_weights,
    kojima_weights,
    neighbour_angle,
    suggest_d_bnd,
    ulr_weights,
)
from workers.sweep.virtual import sphere_lattice


@pytest.mark.parametrize("d12", [0.0, 0.001, 0.0025, 0.0049999, 0.005, 0.02])
def test_kojima_weights_sum_to_one_and_follow_eq6(d12):
    d_bnd = 0.005
    cos1 = 0.99
    w1, w2 = kojima_weights(cos1, cos1 - d12, d_bnd)
    assert w1 + w2 == pytest.approx(1.0, abs=1e-15)
    if d12 >= d_bnd:
        assert (w1, w2) == (1.0, 0.0)  # eq. 3: one-camera region
    else:
        assert w1 == pytest.approx(0.5 * (1 + d12 / d_bnd))  # eq. 5
        assert w2 == pytest.approx(0.5 * (1 - d12 / d_bnd))


def test_kojima_weights_equal_angles_blend_half_and_are_continuous_at_the_boundary():
    assert kojima_weights(0.95, 0.95, 0.01) == (0.5, 0.5)
    d_bnd = 0.01
    below = kojima_weights(0.9, 0.9 - (d_bnd - 1e-12), d_bnd)
    at = kojima_weights(0.9, 0.9 - d_bnd, d_bnd)
    assert at == (1.0, 0.0)
    assert abs(below[0] - at[0]) < 1e-9 and abs(below[1] - at[1]) < 1e-9
    # monotone in D12: the primary's weight grows as the secondary falls behind
    ws = [kojima_weights(0.9, 0.9 - d, d_bnd)[0] for d in np.linspace(0, 0.02, 41)]
    assert all(b >= a for a, b in zip(ws, ws[1:]))


def test_ulr_weights_known_answer():
    out = np.zeros(4)
    theta = np.array([0.1, 0.2, 0.4, 0.8])
    n = ulr_weights(theta, 4, 2, out)  # blend 2, threshold = 3rd angle (0.4)
    assert n == 2
    np.testing.assert_allclose(out[:2], [0.75 / 1.25, 0.5 / 1.25])
    n = ulr_weights(theta, 4, 3, out)  # threshold 0.8
    w = 1 - theta[:3] / 0.8
    np.testing.assert_allclose(out[:3], w / w.sum())
    assert out[:n].sum() == pytest.approx(1.0)


def test_ulr_weights_edge_cases():
    out = np.zeros(4)
    assert ulr_weights(np.array([0.3, 0.0]), 1, 3, out) == 1 and out[0] == 1.0
    # fewer cameras than k + 1: the farthest one sets the threshold and gets weight 0
    n = ulr_weights(np.array([0.1, 0.3]), 2, 3, out)
    assert n == 2
    np.testing.assert_allclose(out[:2], [1.0, 0.0])
    # all angles equal: shared equally
    n = ulr_weights(np.array([0.2, 0.2, 0.2]), 3, 2, out)
    np.testing.assert_allclose(out[:n], [0.5, 0.5])
    # a camera on the virtual ray takes everything
    n = ulr_weights(np.array([0.0, 0.0, 0.3]), 3, 2, out)
    np.testing.assert_allclose(out[:n], [0.5, 0.5])


def test_global_camera_and_suggested_d_bnd():
    axes = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    assert global_camera(axes, np.array([0.1, 0.9, 0.2]) / np.linalg.norm([0.1, 0.9, 0.2])) == 1
    delta = np.radians(10)
    d = suggest_d_bnd(delta, 0.5)
    # the two-camera band is 2 D_bnd / delta wide: half of the angle between the cameras
    assert 2 * d / delta == pytest.approx(0.5 * delta)
    with pytest.raises(ValueError):
        suggest_d_bnd(0.0)


def test_neighbour_angle_of_cameras_on_a_circle():
    a = np.radians([0, 10, 20, 40])
    centers = np.stack([np.cos(a), np.sin(a), np.zeros(4)], axis=1) * 3
    assert neighbour_angle(centers, np.zeros(3)) == pytest.approx(np.radians(10))  # median of 10, 10, 10, 20


def test_neighbour_angle_ignores_cameras_at_the_same_place():
    a = np.radians([0, 0, 10, 30])  # a duplicated pose: its twin is no neighbour
    centers = np.stack([np.cos(a), np.sin(a), np.zeros(4)], axis=1) * 3
    assert neighbour_angle(centers, np.zeros(3)) == pytest.approx(np.radians(10))  # median of 10, 10, 10, 20
    assert neighbour_angle(centers[:2], np.zeros(3)) == 0.0  # no spacing at all


# --- kojima_k: k-camera boundary blending (eq. (6k) in workers/sweep/weighting.py) ------------------------------
def _kojima_k(cos, d_bnd):
    out = np.zeros(len(cos))
    n = kojima_k_weights(np.asarray(cos, np.float64), len(cos), d_bnd, out)
    return out, n


def test_kojima_k_reduces_to_eq6_when_two_cameras_qualify():
    rng = np.random.default_rng(0)
    d_bnd = 0.006
    for _ in range(500):
        cos1 = rng.uniform(0.8, 1.0)
        d12 = rng.uniform(0.0, d_bnd * (1 - 1e-9))
        others = cos1 - rng.uniform(d_bnd, 0.2, size=rng.integers(0, 6))  # D_1i >= D_bnd: not blended
        cos = np.concatenate([[cos1, cos1 - d12], others])
        perm = rng.permutation(len(cos))
        w, n = _kojima_k(cos[perm], d_bnd)
        w = w[np.argsort(perm)]
        w1, w2 = kojima_weights(cos1, cos1 - d12, d_bnd)
        assert n == (2 if d12 < d_bnd and w2 > 0 else 1)
        assert abs(w[0] - w1) < 1e-12 and abs(w[1] - w2) < 1e-12
        assert (w[2:] == 0).all()
        assert w.sum() == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("d12", [0.005, 0.0051, 0.02, 1.0])
def test_kojima_k_keeps_one_camera_regions_one_camera(d12):
    d_bnd = 0.005
    w, n = _kojima_k([0.97 - d12 - 0.001, 0.97, 0.97 - d12, 0.5], d_bnd)  # primary second, D12 >= D_bnd
    assert n == 1
    np.testing.assert_array_equal(w, [0.0, 1.0, 0.0, 0.0])  # exactly C_v = C_1 (eq. 3): no blur


def test_kojima_k_known_answers():
    # D = 0, 0.002, 0.004 with D_bnd 0.005: rho = 1, 3/7, 1/9; sum 97/63
    w, n = _kojima_k([0.99, 0.988, 0.986, 0.9], 0.005)
    assert n == 3
    np.testing.assert_allclose(w, [63 / 97, 27 / 97, 7 / 97, 0.0], rtol=1e-12, atol=1e-15)
    w, n = _kojima_k([0.9, 0.9, 0.9], 0.01)  # three cameras at one angle: a third each
    assert n == 3
    np.testing.assert_allclose(w, [1 / 3] * 3, rtol=1e-15)
    w, n = _kojima_k([0.42], 0.01)
    assert n == 1 and w[0] == 1.0
    assert kojima_k_weights(np.zeros(2), 0, 0.01, np.zeros(2)) == 0


def _lattice_dirs(spacing_deg: float) -> np.ndarray:
    """Unit directions (N, 3) of a triangular lattice of cameras on a sphere around the origin (3 rows)."""
    az, el = np.radians(sphere_lattice(spacing_deg, 3, 5, 20.0)).T
    return np.stack([np.cos(el) * np.sin(az), -np.cos(el) * np.cos(az), np.sin(el)], axis=1)


def _kojima_by_camera(cos, d_bnd):
    """The two-camera rule (eq. 6) as weights per camera: primary and secondary by cosine."""
    order = np.argsort(-cos, kind="stable")
    w = np.zeros(len(cos))
    w[order[0]], w[order[1]] = kojima_weights(cos[order[0]], cos[order[1]], d_bnd)
    return w


def test_kojima_k_weights_are_continuous_along_a_fine_viewpoint_sweep():
    """A virtual viewpoint crosses a triangle of cameras (through the triple point, where three one-camera
    regions meet) in fine steps: the primary, the secondary and the blended set all change on the way. The
    weight change per step obeys the Lipschitz bound of the derivation and shrinks with the step; the
    two-camera rule jumps where the third camera overtakes the secondary, whatever the step."""
    spacing = 10.0
    C = 2.5 * _lattice_dirs(spacing)  # camera centres; the surface point is the origin
    d_bnd = suggest_d_bnd(np.radians(spacing), 0.5)
    a, b, c = C[1], C[2], C[6]  # a triangle (rows 0 and 1)
    start, end = a, (b + c) - a  # from camera a through the triangle's centroid to beyond the edge bc

    def sweep(steps):
        t = np.linspace(0, 1, steps)
        V = start[None] + t[:, None] * (end - start)[None]
        V = 2.5 * V / np.linalg.norm(V, axis=1, keepdims=True)  # viewpoints on the camera sphere
        rv = -V / np.linalg.norm(V, axis=1, keepdims=True)  # virtual rays to the point
        rc = -C / np.linalg.norm(C, axis=1, keepdims=True)  # camera rays to the point
        cos = rv @ rc.T  # (steps, N)
        wk = np.array([_kojima_k(cs, d_bnd)[0] for cs in cos])
        w2 = np.array([_kojima_by_camera(cs, d_bnd) for cs in cos])
        return cos, wk, w2

    cos, wk, w2 = sweep(4001)
    # the path does cross what matters: primary changes, secondary changes and a set of three cameras
    order = np.argsort(-cos, axis=1)
    assert (np.diff(order[:, 0]) != 0).sum() >= 1 and (np.diff(order[:, 1]) != 0).sum() >= 2
    assert ((wk > 0).sum(axis=1) >= 3).any() and ((wk > 0).sum(axis=1) == 1).any()
    np.testing.assert_allclose(wk.sum(axis=1), 1.0, atol=1e-12)
    dw = np.abs(np.diff(wk, axis=0)).sum(axis=1)  # L1 weight change per step
    dc = np.abs(np.diff(cos, axis=0)).max(axis=1)
    n = ((wk[1:] > 0) | (wk[:-1] > 0)).sum(axis=1)  # cameras taking part in either end of a step
    assert (dw <= 8 * n * dc / d_bnd + 1e-12).all()  # the derivation's bound
    # ten times finer: ten times smaller steps in the weights (continuous), but the same jump for kojima
    _, wk_fine, w2_fine = sweep(40001)
    dw_fine = np.abs(np.diff(wk_fine, axis=0)).sum(axis=1)
    assert dw_fine.max() < 0.15 * dw.max()
    jump2 = np.abs(np.diff(w2, axis=0)).sum(axis=1).max()
    jump2_fine = np.abs(np.diff(w2_fine, axis=0)).sum(axis=1).max()
    assert jump2 > 0.2 and jump2_fine > 0.9 * jump2  # the two-camera rule's seam
    assert dw.max() < 0.05


def test_kojima_k_weights_are_symmetric_in_the_cameras():
    rng = np.random.default_rng(1)
    for _ in range(100):
        cos = 0.95 - rng.uniform(0, 0.01, size=6)
        w, _ = _kojima_k(cos, 0.006)
        perm = rng.permutation(6)
        wp, _ = _kojima_k(cos[perm], 0.006)
        np.testing.assert_allclose(wp, w[perm], rtol=1e-13, atol=1e-16)
        # the larger the cosine, the larger the weight; the primary's is the largest
        o = np.argsort(-cos)
        assert (np.diff(w[o]) <= 1e-15).all()
