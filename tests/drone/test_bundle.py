"""Our bundle adjuster: analytic Jacobians, the Schur step against a dense solve, recovery of
perturbed poses (pinhole with known K, and the BAL camera), robust losses, BAL reading."""
import numpy as np
import pytest

from harness.bundle_problem import K, line_of_cameras
from workers.drone import bundle
from workers.drone.bal import read_bal
from workers.drone.camera_models import BALModel, PinholeModel, pose_params, poses_from_params
from workers.drone.geometry import camera_centre, rotation_angle_deg


def test_pinhole_and_bal_jacobians_match_finite_differences():
    R, t, X, ci, pj, obs = line_of_cameras(3, 20)
    for model, params in [(PinholeModel(K, 3), pose_params(R, t)),
                          (BALModel(), np.hstack([pose_params(R, t - [0, 0, 20]), np.tile([400.0, 0.1, -0.02], (3, 1))]))]:
        r, Jc, Jp = model.evaluate(params, X, ci, pj, obs, True)
        eps = 1e-6
        for k in range(model.n_params):
            d = np.zeros_like(params)
            d[:, k] = eps
            r2, _, _ = model.evaluate(model.retract(params, d), X, ci, pj, obs, False)
            np.testing.assert_allclose((r2 - r) / eps, Jc[:, :, k], rtol=1e-4, atol=1e-4 * np.abs(Jc).max())
        for k in range(3):
            Xd = X.copy()
            Xd[:, k] += eps
            r2, _, _ = model.evaluate(params, Xd, ci, pj, obs, False)
            np.testing.assert_allclose((r2 - r) / eps, Jp[:, :, k], rtol=1e-4, atol=1e-4 * np.abs(Jp).max())


def test_schur_step_equals_the_dense_normal_equations():
    R, t, X, ci, pj, obs = line_of_cameras(4, 30, seed=2)
    keep = np.random.default_rng(3).random(len(ci)) < 0.8  # not every camera sees every point
    ci, pj, obs = ci[keep], pj[keep], obs[keep] + np.random.default_rng(4).normal(0, 1, (keep.sum(), 2))
    model = PinholeModel(K, 4)
    params = pose_params(R, t)
    r, Jc, Jp = model.evaluate(params, X, ci, pj, obs, True)
    fixed = np.zeros((4, 6), bool)
    fixed[0] = True
    st = bundle._structure(4, len(X), 6, ci, pj, fixed)
    U, V, W, gc, gp = bundle._normal_blocks(Jc, Jp, r, ci, pj, 4, len(X))
    mu = 1e-3
    blocks, rhs, Vinv = bundle._schur(U, V, W, gc, gp, ci, st.order, st.point_start, st.pair_block, st.pair_start,
                                      st.blk_indptr, st.blk_indices, mu, 1)
    x = bundle._solve_reduced(st, blocks, rhs, 1000)
    dc = np.zeros(24)
    dc[st.free_index >= 0] = x
    dp = bundle._back_substitute(dc.reshape(4, 6), W, Vinv, gp, ci, st.order, st.point_start)
    # Dense reference: the full damped normal equations with the fixed camera removed.
    J = np.zeros((2 * len(ci), 24 + 3 * len(X)))
    for o, (c, p) in enumerate(zip(ci, pj)):
        J[2 * o:2 * o + 2, 6 * c:6 * c + 6] = Jc[o]
        J[2 * o:2 * o + 2, 24 + 3 * p:27 + 3 * p] = Jp[o]
    H = J.T @ J
    H += mu * np.diag(np.clip(np.diag(H), 1e-6, 1e32))
    free = np.r_[~fixed.ravel(), np.ones(3 * len(X), bool)]
    ref = np.zeros(H.shape[0])
    ref[free] = np.linalg.solve(H[np.ix_(free, free)], -(J.T @ r.ravel())[free])
    np.testing.assert_allclose(dc, ref[:24], atol=1e-9 * np.abs(ref).max())
    np.testing.assert_allclose(dp.ravel(), ref[24:], atol=1e-9 * np.abs(ref).max())
    # The sparse LU path agrees with the dense Cholesky one.
    np.testing.assert_allclose(bundle._solve_reduced(st, blocks, rhs, 0), x, rtol=1e-8, atol=1e-12)


def test_ba_recovers_perturbed_poses_and_points():
    R, t, X, ci, pj, obs = line_of_cameras()
    rng = np.random.default_rng(5)
    params = pose_params(R, t)
    noisy = params + np.r_[0, 0, 0, 0, 0, 0, rng.normal(0, [0.02] * 3 + [0.1] * 3, (5, 6)).ravel()].reshape(6, 6)
    Xn = X + rng.normal(0, 0.2, X.shape)
    fixed = np.zeros((6, 6), bool)
    fixed[0] = True
    fixed[1, 3:] = True  # the second camera's (true) translation fixes the scale
    noisy[1, 3:] = params[1, 3:]
    calls = []
    res = bundle.solve(PinholeModel(K, 6), noisy, Xn, ci, pj, obs, fixed, bundle.BAOptions(max_iterations=50),
                       callback=lambda i, c: calls.append((i, c)))
    assert res.initial_cost > 1e3 and res.final_cost < 1e-12
    Rr, tr = poses_from_params(res.params)
    # Stopped by the gradient tolerance (1e-10 of the first gradient) at a cost near 1e-16.
    assert rotation_angle_deg(Rr, R).max() < 1e-5
    np.testing.assert_allclose(camera_centre(Rr, tr), camera_centre(R, t), atol=1e-6)
    np.testing.assert_allclose(res.points, X, atol=1e-6)
    assert calls and calls[-1][0] == res.iterations
    assert all(b <= a for a, b in zip(res.history, res.history[1:]))


def test_bal_camera_refines_focal_and_distortion():
    R, t, X, ci, pj, _ = line_of_cameras(5, 200, seed=6)
    # BAL looks down -z: flip the scene, give each camera f, k1, k2, and project with the model.
    flip = np.diag([1.0, -1.0, -1.0])
    truth = np.hstack([pose_params(flip @ R, t @ flip), np.tile([400.0, -0.05, 0.01], (5, 1))])
    model = BALModel()
    obs = np.zeros((len(ci), 2))
    r, _, _ = model.evaluate(truth, X, ci, pj, obs, False)
    obs = r  # residual against zero = the projection
    start = truth.copy()
    start[1:, 6] *= 1.03
    start[1:, 7:] = 0.0
    start[1:, :6] += np.random.default_rng(7).normal(0, [0.01] * 3 + [0.05] * 3, (4, 6))
    fixed = np.zeros((5, 9), bool)
    fixed[0] = True
    fixed[1, 3:6] = True
    start[1, 3:6] = truth[1, 3:6]
    res = bundle.solve(model, start, X + 0.05, ci, pj, obs, fixed, bundle.BAOptions(max_iterations=100))
    assert res.final_cost < 1e-10
    np.testing.assert_allclose(res.params[:, 6:], truth[:, 6:], rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_robust_loss_resists_outliers(loss):
    R, t, X, ci, pj, obs = line_of_cameras(seed=8)
    rng = np.random.default_rng(9)
    obs = obs + rng.normal(0, 0.3, obs.shape)
    bad = rng.random(len(obs)) < 0.05
    obs[bad] += rng.uniform(15, 40, (bad.sum(), 2))
    params = pose_params(R, t)
    start = params.copy()
    start[1:] += rng.normal(0, [0.01] * 3 + [0.05] * 3, (5, 6))
    fixed = np.zeros((6, 6), bool)
    fixed[0] = True
    fixed[1, 3:] = True
    start[1, 3:] = params[1, 3:]
    errs = {}
    for name in ("trivial", loss):
        res = bundle.solve(PinholeModel(K, 6), start, X, ci, pj, obs, fixed,
                           bundle.BAOptions(max_iterations=100, loss=name, loss_scale=1.0))
        Rr, tr = poses_from_params(res.params)
        errs[name] = np.linalg.norm(camera_centre(Rr, tr) - camera_centre(R, t), axis=1).max()
    assert errs[loss] < 0.5 * errs["trivial"]
    assert errs[loss] < 0.03


def test_read_bal(tmp_path):
    text = "2 3 4\n0 0 1.0 -2.0\n1 0 3.0 4.0\n0 1 5 6\n1 2 7 8\n" + "\n".join(str(v) for v in range(18 + 9)) + "\n"
    path = tmp_path / "p.txt"
    path.write_text(text)
    prob = read_bal(path)
    assert prob.params.shape == (2, 9) and prob.points.shape == (3, 3)
    np.testing.assert_array_equal(prob.cam_idx, [0, 1, 0, 1])
    np.testing.assert_array_equal(prob.obs[1], [3.0, 4.0])
    assert prob.points[2, 2] == 26
    path.write_text("2 3 5\n" + text.split("\n", 1)[1])
    with pytest.raises(ValueError):
        read_bal(path)


def test_one_iteration_runs_as_named_steps_and_its_model_decrease_is_positive():
    R, t, X, ci, pj, obs = line_of_cameras(4, 60, seed=3)
    params = pose_params(R, t)
    noisy = params + np.random.default_rng(3).normal(0, 0.01, params.shape)
    fixed = np.zeros(params.shape, bool)
    fixed[0] = True
    seen: dict[str, object] = {}

    def step(name, fn):
        seen[name] = fn()
        return seen[name]

    size = bundle.iteration_steps(PinholeModel(K, 4), noisy, X + 0.01, ci, pj, obs, fixed, step)
    assert list(seen) == ["residuals_and_jacobians", "normal_equation_blocks", "schur_complement",
                          "reduced_system_cholesky", "back_substitution", "model_decrease"]
    assert size == {"reduced_unknowns": 3 * 6, "point_pairs": size["point_pairs"]} and size["point_pairs"] > 0
    assert seen["model_decrease"] > 0  # the damped step predicts a lower cost
