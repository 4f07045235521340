"""The four weightings on constructed angle cases (eqs. 1-6 and the ULR formula)."""
import numpy as np
import pytest

from workers.sweep.weighting import global_camera, kojima_weights, neighbour_angle, suggest_d_bnd, ulr_weights


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
