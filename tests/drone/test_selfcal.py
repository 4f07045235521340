"""Self-calibration: the shared-intrinsics camera model, the bordered bundle adjustment with priors,
what the images say about the focal length, the radial lens on pixels, and where focal lengths start."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from workers.drone import bundle
from workers.drone.camera_models import RadialModel, pose_params, poses_from_params
from workers.drone.evaluation import trajectory_error
from workers.drone.exif import PhotoMeta
from workers.drone.selfcal import (default_focal_prior, distort_pixels, focal_from_35mm, focal_prior_from_exif,
                                   undistort_pixels)

F, K1, K2 = 500.0, -0.08, 0.01
CENTRE = (319.5, 239.5)


def _problem(relief: float, tilt_deg: float, seed: int = 0, n_cams: int = 10):
    """Cameras 60 m above ground, looking down with random tilts of ``tilt_deg``, over points with
    ``relief`` metres of height variation; observations through the radial lens with 0.2 px noise."""
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(-45, 45, 900), rng.uniform(-35, 35, 900), rng.uniform(0, relief, 900)])
    down = np.diag([1.0, -1.0, -1.0])
    R, t = [], []
    for i in range(n_cams):
        C = np.array([-30 + 60 * i / (n_cams - 1), 8 * np.sin(i), 60.0 + rng.normal(0, 1)])
        turn = cv2.Rodrigues(rng.normal(0, np.radians(tilt_deg), 3))[0]
        R.append(turn @ down)
        t.append(-R[-1] @ C)
    R, t = np.array(R), np.array(t)
    ci, pj = (a.ravel() for a in np.meshgrid(np.arange(n_cams), np.arange(len(X)), indexing="ij"))
    params = pose_params(R, t)
    r, _, _ = RadialModel(CENTRE, np.array([F, K1, K2])).evaluate(params, X, ci, pj, np.zeros((len(ci), 2)), False)
    P = np.einsum("nij,nj->ni", R[ci], X[pj]) + t[ci]
    keep = (r[:, 0] > 0) & (r[:, 0] < 640) & (r[:, 1] > 0) & (r[:, 1] < 480) & (P[:, 2] > 0)
    obs = r[keep] + rng.normal(0, 0.2, (int(keep.sum()), 2))
    return params, X, ci[keep], pj[keep], obs, R, t


def test_radial_model_jacobians_match_finite_differences():
    _, X, ci, pj, obs, R, t = _problem(5.0, 3.0)
    # The same views in a world whose z points down: rotations near 0, not near pi, where a rotation
    # vector's round trip loses digits that finite differences would see.
    Q = np.diag([1.0, -1.0, -1.0])
    X, params = X @ Q, pose_params(R @ Q, t)
    model = RadialModel(CENTRE)
    shared = np.array([F, K1, K2])
    r0, Jc, Jp, Jg = model.evaluate_shared(params, shared, X, ci, pj, obs, True)
    for a, step in enumerate((1e-4, 1e-7, 1e-7)):
        d = np.zeros(3)
        d[a] = step
        r1 = model.evaluate_shared(params, shared + d, X, ci, pj, obs, False)[0]
        np.testing.assert_allclose((r1 - r0) / step, Jg[:, :, a], atol=1e-3 * np.abs(Jg[:, :, a]).max())
    # the principal point as two more shared parameters: the same residuals at the same point, and its columns
    with_centre = RadialModel((0.0, 0.0), refine_centre=True)
    assert with_centre.n_shared == 5
    shared5 = np.array([F, K1, K2, *CENTRE])
    r5, Jc5, _, Jg5 = with_centre.evaluate_shared(params, shared5, X, ci, pj, obs, True)
    np.testing.assert_allclose(r5, r0)
    np.testing.assert_allclose(Jg5[:, :, :3], Jg)
    np.testing.assert_allclose(Jc5, Jc)
    for a in (3, 4):
        d = np.zeros(5)
        d[a] = 0.5
        r1 = with_centre.evaluate_shared(params, shared5 + d, X, ci, pj, obs, False)[0]
        np.testing.assert_allclose((r1 - r5) / 0.5, Jg5[:, :, a], atol=1e-9)
    for a in range(6):
        d = np.zeros_like(params)
        d[:, a] = 1e-7
        r1 = model.evaluate_shared(model.retract(params, d), shared, X, ci, pj, obs, False)[0]
        np.testing.assert_allclose((r1 - r0) / 1e-7, Jc[:, :, a], atol=2e-3 * np.abs(Jc[:, :, a]).max())
    dX = np.zeros_like(X)
    dX[:, 2] = 1e-6
    r1 = model.evaluate_shared(params, shared, X + dX, ci, pj, obs, False)[0]
    np.testing.assert_allclose((r1 - r0) / 1e-6, Jp[:, :, 2], atol=1e-3 * np.abs(Jp[:, :, 2]).max())


def test_bundle_adjustment_recovers_focal_length_and_distortion_from_a_wrong_start():
    params, X, ci, pj, obs, _, _ = _problem(relief=15.0, tilt_deg=8.0)
    rng = np.random.default_rng(1)
    start = params.copy()
    start[:, 3:] += rng.normal(0, 0.3, start[:, 3:].shape)
    fixed = np.zeros(params.shape, bool)
    fixed[0] = True
    res = bundle.solve(RadialModel(CENTRE), start, X + rng.normal(0, 0.3, X.shape), ci, pj, obs, fixed,
                       bundle.BAOptions(max_iterations=100), shared=np.array([450.0, 0.0, 0.0]))
    f, k1, k2 = res.shared
    # The gauge leaves the scale free, not the focal length: it is recovered to the noise.
    assert f == pytest.approx(F, rel=0.005)
    assert k1 == pytest.approx(K1, abs=0.005) and k2 == pytest.approx(K2, abs=0.005)
    assert np.sqrt(2 * res.final_cost / len(obs)) < 0.3  # per-axis residual at the 0.2 px noise


def test_shared_parameters_can_be_held_and_priors_pull():
    params, X, ci, pj, obs, _, _ = _problem(relief=15.0, tilt_deg=8.0)
    fixed = np.zeros(params.shape, bool)
    fixed[0] = True
    held = bundle.solve(RadialModel(CENTRE), params, X, ci, pj, obs, fixed, bundle.BAOptions(max_iterations=30),
                        shared=np.array([520.0, 0.0, 0.0]), shared_fixed=np.array([True, False, True]))
    assert held.shared[0] == 520.0 and held.shared[2] == 0.0 and held.shared[1] != 0.0
    pulled = bundle.solve(RadialModel(CENTRE), params, X, ci, pj, obs, fixed, bundle.BAOptions(max_iterations=50),
                          shared=np.array([F, K1, K2]),
                          shared_prior=bundle.SharedPrior(np.array([400.0, 0.0, 0.0]), np.array([0.01, np.inf, np.inf])))
    assert pulled.shared[0] == pytest.approx(400.0, abs=0.5)  # a prior of 0.01 px wins


def test_the_images_of_a_flat_nadir_flight_do_not_determine_the_focal_length():
    sigmas = {}
    for name, relief, tilt in (("flat_nadir", 0.0, 0.3), ("relief_and_tilt", 15.0, 8.0)):
        params, X, ci, pj, obs, _, _ = _problem(relief, tilt)
        fixed = np.zeros(params.shape, bool)
        fixed[0] = True
        info = bundle.shared_information(RadialModel(CENTRE), params, X, np.array([F, K1, K2]), ci, pj, obs, fixed)
        sigmas[name] = float(np.sqrt(np.linalg.inv(info)[0, 0]))
    # Flat ground from straight above: focal length, altitude and distortion trade off (almost) exactly.
    assert sigmas["flat_nadir"] > 20 * sigmas["relief_and_tilt"]
    assert sigmas["relief_and_tilt"] < 2.0


def test_centre_prior_fixes_the_gauge_at_the_gps_positions():
    params, X, ci, pj, obs, R, t = _problem(relief=10.0, tilt_deg=5.0)
    centres = -np.einsum("nji,nj->ni", R, t)
    rng = np.random.default_rng(2)
    # Start from a shifted, scaled copy of the truth: only the prior can say where and how large it is.
    Rs, ts = poses_from_params(params)
    start = pose_params(Rs, 1.1 * ts + 3.0)
    gps = centres + rng.normal(0, 0.05, centres.shape)
    res = bundle.solve(RadialModel(CENTRE), start, 1.1 * X, ci, pj, obs, np.zeros(params.shape, bool),
                       bundle.BAOptions(max_iterations=100), shared=np.array([F, K1, K2]),
                       shared_fixed=np.ones(3, bool),
                       centre_prior=bundle.CentrePrior(gps, np.full(len(centres), 0.05)))
    R1, t1 = poses_from_params(res.params)
    found = -np.einsum("nji,nj->ni", R1, t1)

    def rms(a):
        return np.sqrt(np.mean(np.sum((a - centres) ** 2, axis=1)))

    # In place and to scale, and closer to the truth than the noisy positions themselves (the images
    # keep the shape rigid, the prior only places it).
    assert rms(found) < 0.75 * rms(gps) < 0.1


def test_undistort_inverts_distort_and_agrees_with_opencv():
    rng = np.random.default_rng(3)
    xy = rng.uniform([0, 0], [640, 480], (500, 2))
    c = np.array(CENTRE)
    raw = distort_pixels(xy, F, K1, K2, c)
    np.testing.assert_allclose(undistort_pixels(raw, F, K1, K2, c), xy, atol=1e-8)
    K = np.array([[F, 0, c[0]], [0, F, c[1]], [0, 0, 1]])
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    cv = cv2.undistortPointsIter(raw.reshape(-1, 1, 2), K, np.array([K1, K2, 0, 0]), None, K, crit).reshape(-1, 2)
    np.testing.assert_allclose(undistort_pixels(raw, F, K1, K2, c), cv, atol=1e-6)


def test_focal_length_sources():
    fc350 = PhotoMeta(make="DJI", model="FC350", focal_mm=3.61, focal_35mm=20.0)
    prior = focal_prior_from_exif(fc350, 1200, 900)
    assert prior.source == "exif_sensor_table" and prior.focal_px == pytest.approx(702.1, abs=0.05)
    # The same camera unknown to the table: the 35 mm equivalent by the diagonal (COLMAP: 693.3 px).
    other = focal_prior_from_exif(PhotoMeta(model="X", focal_mm=3.61, focal_35mm=20.0), 1200, 900)
    assert other.source == "exif_35mm" and other.focal_px == pytest.approx(693.4, abs=0.05)
    plane = focal_prior_from_exif(PhotoMeta(focal_mm=4.0, focal_plane_mm_per_px=0.004, exif_width=4000), 1000, 750)
    assert plane.source == "exif_focal_plane" and plane.focal_px == pytest.approx(250.0)
    assert focal_prior_from_exif(PhotoMeta(), 1200, 900) is None
    video = default_focal_prior(1920)
    assert video.source == "default_fov" and video.focal_px == pytest.approx(960 / np.tan(np.radians(36)))
    assert focal_from_35mm(43.2666, 1200, 900) == pytest.approx(1500, rel=1e-4)
    assert prior.sigma < other.sigma < plane.sigma < video.sigma


def _serpentine(centre: tuple[float, float], seed: int = 3):
    """Two flight lines at 60 m over gently rolling ground (5 m), the second flown back with the camera turned by
    180 degrees (it faces the way it flies), 1 degree tilts; observed through a lens whose principal point is
    ``centre``, 0.2 px noise. Returns params, points, ci, pj, obs."""
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(-50, 50, 1500), rng.uniform(-45, 45, 1500), rng.uniform(0, 5, 1500)])
    down = np.diag([1.0, -1.0, -1.0])
    back = np.diag([-1.0, -1.0, 1.0]) @ down  # turned about the vertical by 180 degrees
    R, t = [], []
    for line, (y, base) in enumerate(((-12.0, down), (12.0, back))):
        for i in range(8):
            x = -35 + 70 * i / 7
            C = np.array([x if line == 0 else -x, y, 60.0 + rng.normal(0, 0.5)])
            R.append(cv2.Rodrigues(rng.normal(0, np.radians(1.0), 3))[0] @ base)
            t.append(-R[-1] @ C)
    R, t = np.array(R), np.array(t)
    ci, pj = (a.ravel() for a in np.meshgrid(np.arange(len(R)), np.arange(len(X)), indexing="ij"))
    params = pose_params(R, t)
    r, _, _ = RadialModel(centre, np.array([F, K1, K2])).evaluate(params, X, ci, pj, np.zeros((len(ci), 2)), False)
    P = np.einsum("nij,nj->ni", R[ci], X[pj]) + t[ci]
    keep = (r[:, 0] > 0) & (r[:, 0] < 640) & (r[:, 1] > 0) & (r[:, 1] < 480) & (P[:, 2] > 0)
    return params, X, ci[keep], pj[keep], r[keep] + rng.normal(0, 0.2, (int(keep.sum()), 2))


def test_the_principal_point_is_found_where_flight_lines_turn_the_camera_around():
    """A principal point 9 px left of and 4 px below the image centre (as sfm/drone_fc350's ~8 px): refined from the
    centre under the reconstruction's prior, it is found to a pixel and the fit reaches the noise; held at the
    centre, the same adjustment moves the camera centres (0.7 m against 0.02 m, after a similarity to the truth)."""
    true_centre = (CENTRE[0] - 9.0, CENTRE[1] + 4.0)
    params, X, ci, pj, obs = _serpentine(true_centre)
    rng = np.random.default_rng(4)
    start = params.copy()
    start[:, 3:] += rng.normal(0, 0.2, start[:, 3:].shape)
    fixed = np.zeros(params.shape, bool)
    fixed[0] = True
    options = bundle.BAOptions(max_iterations=100)
    sigma_c = 0.01 * 640
    refined = bundle.solve(RadialModel(CENTRE, refine_centre=True), start, X + rng.normal(0, 0.2, X.shape), ci, pj,
                           obs, fixed, options, shared=np.array([F, 0.0, 0.0, *CENTRE]),
                           shared_prior=bundle.SharedPrior(np.array([F, 0.0, 0.0, *CENTRE]),
                                                           np.array([0.02 * F, 0.25, 0.25, sigma_c, sigma_c])))
    assert refined.shared[3:] == pytest.approx(true_centre, abs=1.0)
    assert np.sqrt(2 * refined.final_cost / len(obs)) < 0.3
    held = bundle.solve(RadialModel(CENTRE), start, X, ci, pj, obs, fixed, options, shared=np.array([F, 0.0, 0.0]))

    def centres(p: np.ndarray) -> np.ndarray:
        R, t = poses_from_params(p)
        return -np.einsum("nji,nj->ni", R, t)

    truth = centres(params)
    errors = {name: np.linalg.norm(trajectory_error(centres(res.params), truth).alignment.apply(centres(res.params))
                                   - truth, axis=1).mean() for name, res in (("refined", refined), ("held", held))}
    assert errors["held"] > 10 * errors["refined"]  # held: the lines sit sideways of where they flew
