"""Two-view geometry with known answers: E, pose by SVD + cheirality, DLT triangulation, PnP,
the planar-scene ambiguity, rotation parameters, Sim(3) alignment."""
import numpy as np
import pytest

from workers.drone.camera_models import pose_params, poses_from_params
from workers.drone.evaluation import trajectory_error, umeyama
from workers.drone.geometry import (camera_centre, decompose_essential, essential_from_pose, normalise,
                                    pose_from_essential, project, rotation_angle_deg, triangulate_dlt)
from workers.drone.matching import estimate_essential
from workers.drone.multiview import register_pnp, triangulate_pairs, two_view

K = np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])


def _rot(axis, deg):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    th = np.radians(deg)
    A = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(th) * A + (1 - np.cos(th)) * A @ A


def _scene(n=300, seed=0, depth=(4, 12)):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-3, 3, n), rng.uniform(-2, 2, n), rng.uniform(*depth, n)])


def test_pose_from_essential_recovers_motion():
    R = _rot([0.2, 1, 0.1], 8)
    t = np.array([1.0, 0.1, 0.2])
    X = _scene()
    m0 = project(K, np.eye(3), np.zeros(3), X)
    m1 = project(K, R, t, X)
    E = essential_from_pose(R, t)
    x0, x1 = normalise(K, m0), normalise(K, m1)
    # The epipolar constraint of eq. (4) holds exactly.
    h0, h1 = np.column_stack([x0, np.ones(len(X))]), np.column_stack([x1, np.ones(len(X))])
    assert np.abs(np.einsum("ni,ij,nj->n", h1, E, h0)).max() < 1e-12
    assert len(decompose_essential(E)) == 4
    R_est, t_est, front = pose_from_essential(E, x0, x1)
    assert front.all()
    assert rotation_angle_deg(R_est, R) < 1e-8
    np.testing.assert_allclose(t_est, t / np.linalg.norm(t), atol=1e-9)


def test_ransac_essential_rejects_injected_outliers():
    R, t = _rot([0, 1, 0], 5), np.array([0.8, 0.0, 0.1])
    X = _scene(400, seed=1)
    m0 = project(K, np.eye(3), np.zeros(3), X)
    m1 = project(K, R, t, X) + np.random.default_rng(2).normal(0, 0.2, (400, 2))
    bad = np.arange(0, 400, 5)  # 20% outliers, moved by 20-60 px
    m1[bad] += np.random.default_rng(3).uniform(20, 60, (len(bad), 2)) * np.random.default_rng(4).choice([-1, 1], (len(bad), 2))
    E, inl = estimate_essential(m0, m1, K, 1.0)
    assert not inl[bad].any()
    assert inl.sum() >= 0.95 * (400 - len(bad))
    R_est, t_est, _ = pose_from_essential(E, normalise(K, m0[inl]), normalise(K, m1[inl]))
    assert rotation_angle_deg(R_est, R) < 0.2
    assert np.degrees(np.arccos(np.clip(t_est @ t / np.linalg.norm(t), -1, 1))) < 2.0


def test_dlt_triangulation_exact_and_noisy():
    R, t = _rot([0, 1, 0], -6), np.array([-1.0, 0.05, 0.0])
    X = _scene(200, seed=5)
    P0 = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P1 = K @ np.hstack([R, t[:, None]])
    m0, m1 = project(K, np.eye(3), np.zeros(3), X), project(K, R, t, X)
    np.testing.assert_allclose(triangulate_dlt(P0, P1, m0, m1), X, atol=1e-8)
    rng = np.random.default_rng(6)
    Xn = triangulate_dlt(P0, P1, m0 + rng.normal(0, 0.3, m0.shape), m1 + rng.normal(0, 0.3, m1.shape))
    rel = np.linalg.norm(Xn - X, axis=1) / np.linalg.norm(X, axis=1)
    assert np.median(rel) < 0.01
    # Per-point camera stacks give the same answer.
    Xs, ok = triangulate_pairs(K, np.eye(3), np.zeros(3), m0, np.broadcast_to(R, (200, 3, 3)),
                               np.broadcast_to(t, (200, 3)), m1, 1.0, 0.5)
    np.testing.assert_allclose(Xs[ok], X[ok], atol=1e-8)
    assert ok.mean() > 0.9


def test_two_view_picks_the_true_pose_over_a_nearly_flat_scene():
    # A nadir camera 100 m above ground with 2 m relief; the motion is sideways.
    rng = np.random.default_rng(7)
    n = 600
    X = np.column_stack([rng.uniform(-60, 60, n), rng.uniform(-45, 45, n), 100 + rng.uniform(-2, 0, n)])
    R, t_c = _rot([0.1, 0.2, 1.0], 3), np.array([25.0, 2.0, 0.5])
    t = -R @ t_c
    m0 = project(K, np.eye(3), np.zeros(3), X) + rng.normal(0, 0.3, (n, 2))
    m1 = project(K, R, t, X) + rng.normal(0, 0.3, (n, 2))
    tv = two_view(m0, m1, K, 1.0, 4.0, 0.5)
    assert tv is not None
    assert rotation_angle_deg(tv.R, R) < 0.5
    assert np.degrees(np.arccos(np.clip(tv.t @ t / np.linalg.norm(t), -1, 1))) < 3.0
    assert tv.good.sum() > 0.8 * n


def test_pnp_registers_a_frame_with_outliers():
    R, t = _rot([1, 0.3, 0], 10), np.array([0.5, -0.2, 1.0])
    X = _scene(150, seed=8)
    m = project(K, R, t, X) + np.random.default_rng(9).normal(0, 0.2, (150, 2))
    m[:20] += 40.0
    res = register_pnp(X, m, K, 3.0)
    assert res is not None
    R_est, t_est, inl = res
    assert not inl[:20].any() and inl[20:].mean() > 0.95
    assert rotation_angle_deg(R_est, R) < 0.2
    np.testing.assert_allclose(camera_centre(R_est, t_est), camera_centre(R, t), atol=0.05)


def test_rotation_parameters_roundtrip_up_to_pi():
    Rs = np.stack([_rot(a, d) for a, d in [([1, 0, 0], 0), ([0, 1, 0], 90), ([1, 1, 0], 179.9999),
                                           ([0, 0, 1], 180), ([1, 2, 3], 37)]])
    params = pose_params(Rs, np.zeros((5, 3)))
    R2, _ = poses_from_params(params)
    np.testing.assert_allclose(R2, Rs, atol=1e-9)


def test_umeyama_and_ate_recover_a_similarity():
    rng = np.random.default_rng(10)
    C = rng.normal(size=(20, 3))
    A, s, b = _rot([1, 2, 0.5], 40), 3.5, np.array([10.0, -2.0, 5.0])
    gt = s * C @ A.T + b
    sim = umeyama(C, gt)
    assert sim.s == pytest.approx(s)
    np.testing.assert_allclose(sim.R, A, atol=1e-10)
    Rg = np.stack([_rot(rng.normal(size=3), 20) for _ in range(20)])
    te = trajectory_error(C, gt, Rg @ A, Rg)
    assert te.ate_rmse < 1e-9 and te.rotation_mean_deg < 1e-6
