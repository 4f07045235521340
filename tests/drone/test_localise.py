"""Every decoded frame gets a pose: frames outside the map registered by PnP (workers.drone.localise),
their trajectory entries, and the reasons of the frames that cannot be registered."""
import json

import cv2
import numpy as np
import pytest

from workers.drone.calibration import from_values
from workers.drone.evaluation import trajectory_error
from workers.drone.export import trajectory, trajectory_json
from workers.drone.frames import Skipped, open_media, select_frames
from workers.drone.geometry import camera_centre, project
from workers.drone.localise import follow_skipped, locate
from workers.drone.params import ReconstructionParams
from workers.drone.reconstruction import reconstruct

K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])


def test_selection_reports_every_frame_it_leaves_out(tmp_path):
    """Each decoded frame is either yielded or passed to on_skipped, with its reason and its gray
    image at the working resolution, before the next selected frame comes."""
    from workers.synth.flight import encode_video

    rng = np.random.default_rng(0)
    base = cv2.resize(rng.integers(0, 256, (60, 80, 3), dtype=np.uint8), (640, 480), interpolation=cv2.INTER_CUBIC)
    frames = [np.roll(base, 4 * i, axis=1)[:240, :320].copy() for i in range(24)]
    frames[11] = cv2.GaussianBlur(frames[11], (0, 0), 4)
    path = encode_video(frames, tmp_path / "v.mp4")
    events = []
    for f in select_frames(open_media(path), from_values(300, 300, 159.5, 119.5), None, min_motion=10 / 320,
                           blur_ratio=0.5, max_width=160, on_skipped=lambda s: events.append(("skip", s))):
        events.append(("take", f))
    assert [e[1].index for e in events] == list(range(24))  # in decoding order, none lost
    skipped = {e[1].index: e[1] for e in events if e[0] == "skip"}
    assert skipped and all(s.gray.shape == (120, 160) and s.gray.dtype == np.uint8 for s in skipped.values())
    assert {s.reason for i, s in skipped.items() if i != 11} == {"little motion since the last selected frame"}
    assert skipped[11].reason == "blurred"
    steps = []
    list(select_frames(open_media(path), from_values(300, 300, 159.5, 119.5), frame_step=3, blur_ratio=0.0,
                       on_skipped=steps.append))
    assert [s.index for s in steps] == [i for i in range(24) if i % 3] and steps[0].reason.startswith("frame_step")


def _rotation(rvec):
    return cv2.Rodrigues(np.asarray(rvec, np.float64))[0]


def test_locate_recovers_a_known_pose_despite_outliers():
    rng = np.random.default_rng(0)
    X = rng.uniform([-5, -4, 8], [5, 4, 14], size=(200, 3))
    R, t = _rotation([0.05, -0.1, 0.02]), np.array([0.3, -0.2, 0.5])
    xy = project(K, R, t, X) + rng.normal(0, 0.3, (200, 2))
    xy[:40] += rng.uniform(20, 60, (40, 2))  # 20 % gross outliers
    loc = locate(X, xy, K, threshold=2.0)
    assert loc.failure is None and loc.candidates == 200
    assert 150 <= loc.inliers <= 165  # the 160 good points, give or take noise at the threshold
    assert np.allclose(loc.R, R, atol=2e-3) and np.allclose(loc.t, t, atol=0.02)


def test_locate_says_why_it_fails():
    rng = np.random.default_rng(1)
    X = rng.uniform([-5, -4, 8], [5, 4, 14], size=(200, 3))
    few = locate(X[:8], project(K, np.eye(3), np.zeros(3), X[:8]), K, 2.0)
    assert few.R is None and few.candidates == 8 and "fewer than 12" in few.failure
    noise = locate(X, rng.uniform(0, 320, (200, 2)), K, 0.5)  # no consistent pose
    assert noise.R is None and noise.candidates == 200 and "no PnP pose" in noise.failure


def test_follow_skipped_tracks_the_last_frame_features_into_a_shifted_frame():
    rng = np.random.default_rng(2)
    big = cv2.GaussianBlur(rng.integers(0, 255, (280, 360), np.uint8), (0, 0), 2.0)
    gray0, gray1 = big[20:260, 20:340], big[18:258, 17:337]  # content moves by (+3, +2) px
    pts = cv2.goodFeaturesToTrack(gray0, 300, 0.01, 8)[:, 0]
    pts = pts[(pts[:, 0] > 15) & (pts[:, 0] < 300) & (pts[:, 1] > 15) & (pts[:, 1] < 220)].astype(np.float32)
    keys = np.arange(100, 100 + len(pts), dtype=np.int64)
    view = follow_skipped(Skipped(7, 0.28, "frame_000007", gray1, "little motion"), (gray0, keys, pts), 3,
                          fb_threshold=1.0, window=21, levels=3, max_points=1000)
    assert view.failure is None and view.index == 7 and view.after == 3
    assert len(view.keys) > 0.9 * len(pts)
    moved = view.xy - pts[np.searchsorted(keys, view.keys)]
    assert np.allclose(np.median(moved, axis=0), [3.0, 2.0], atol=0.05)
    capped = follow_skipped(Skipped(7, None, "f", gray1, "blurred"), (gray0, keys, pts), 3, 1.0, 21, 3, max_points=50)
    assert len(capped.keys) <= 50
    unusable = follow_skipped(Skipped(8, None, "f", None, "size differs from the first frame"), (gray0, keys, pts),
                              3, 1.0, 21, 3)
    assert unusable.failure == "not usable: size differs from the first frame" and len(unusable.keys) == 0
    assert follow_skipped(Skipped(0, None, "f", gray1, "x"), None, -1, 1.0, 21, 3).failure


def _truth_error(flight, frames, R, t):
    Cg = np.stack([flight.cameras[i].center for i in frames])
    Rg = np.stack([flight.cameras[i].R for i in frames])
    return trajectory_error(camera_centre(R, t), Cg, R, Rg)


@pytest.mark.parametrize("selection", ["frame_step", "motion"])
def test_every_decoded_frame_gets_a_pose(flight, selection):
    K = flight.K
    params = (ReconstructionParams(frame_step=3, max_features=800) if selection == "frame_step"
              else ReconstructionParams(min_motion=0.03, max_features=800))
    model = reconstruct(flight.path, from_values(K[0, 0], K[1, 1], K[0, 2], K[1, 2]), params)
    n = len(flight.frames)
    assert 0 < len(model.frame_index) < n and len(model.skipped) == n - len(model.frame_index)
    traj = json.loads(trajectory_json(model))
    frames = traj["frames"]
    assert [f["frame"] for f in frames] == list(range(n))
    assert traj["counts"]["decoded"] == n and traj["counts"]["selected"] == len(model.frame_index)
    skipped = [f for f in frames if not f["selected"]]
    assert all(f["registered"] and f["registration"] == "pnp" and f["inliers"] >= 12 for f in skipped)
    expected = "frame_step" if selection == "frame_step" else "little motion"
    reasons = [f["skipped_because"] for f in skipped]
    assert all(r.startswith(expected) or r == "blurred" for r in reasons)  # a due frame may be blurred
    assert sum(r.startswith(expected) for r in reasons) >= len(reasons) - 2
    mapped = [f for f in frames if f["registration"] == "map"]
    assert all(f["selected"] and f["inliers"] > 0 for f in mapped)
    assert traj["counts"]["registered"] == n and traj["unregistered"] == []
    assert traj["counts"]["registered_in_map"] + traj["counts"]["registered_afterwards"] == n
    # All poses, the skipped frames' included, lie on the true path (one similarity for all).
    R = np.array([f["R"] for f in frames])
    t = np.array([f["t"] for f in frames])
    err = _truth_error(flight, range(n), R, t)
    path = np.linalg.norm(np.diff([c.center for c in flight.cameras], axis=0), axis=1).sum()
    assert err.ate_rmse < 0.01 * path and err.rotation_mean_deg < 0.5
    # The skipped frames alone, under that alignment, are no worse than 2 % of the path each.
    aligned = np.linalg.norm(err.alignment.apply(camera_centre(R, t)) - np.stack([c.center for c in flight.cameras]),
                             axis=1)
    assert aligned[[f["frame"] for f in skipped]].max() < 0.02 * path
    rep = model.report["frames"]
    assert rep["skipped_by_selection"] == len(skipped) and rep["skipped_registered"] == len(skipped)


def test_a_frame_that_cannot_be_registered_is_listed_with_its_reason(flight):
    """A frame the map does not see (a blank frame spliced into the video, left out by the frame
    step) keeps its reason; the frames around it are posed."""
    from workers.synth.flight import encode_video

    frames = [f.copy() for f in flight.frames]
    frames[11] = np.full_like(frames[11], 128)
    path = encode_video(frames, flight.path.parent / "blank.mp4", fps=25)
    K = flight.K
    model = reconstruct(path, from_values(K[0, 0], K[1, 1], K[0, 2], K[1, 2]),
                        ReconstructionParams(frame_step=2, max_features=800, blur_ratio=0.0))
    traj = trajectory(model)
    blank = traj["frames"][11]
    assert blank["frame"] == 11 and not blank["selected"] and not blank["registered"]
    assert "fewer than 12" in blank["reason"] and "R" not in blank
    assert traj["unregistered"] == [{"frame": 11, "name": blank["name"], "reason": blank["reason"]}]
    assert traj["counts"]["registered"] == 35


def test_the_final_adjustment_refines_the_frames_registered_by_pnp(flight):
    """With ``joint_ba`` the selected non-keyframes, first posed by PnP against the map, join the
    final bundle adjustment with their tracked observations: each has observations in the model,
    and their poses lie on the true path at least as well as the PnP poses alone."""
    K = flight.K
    n = len(flight.frames)
    runs = {}
    for joint in (False, True):
        model = reconstruct(flight.path, from_values(K[0, 0], K[1, 1], K[0, 2], K[1, 2]),
                            ReconstructionParams(max_features=800, keyframe_parallax=0.06, joint_ba=joint))
        pnp = [f for f in range(len(model.frame_index)) if model.frame_registration[f] == "pnp"]
        assert len(pnp) >= 5 and model.registered.all()
        observed = np.bincount(model.obs_frame, minlength=len(model.frame_index))
        assert (observed[pnp] > 0).all() == joint  # only the joint adjustment keeps their observations
        assert trajectory(model)["counts"]["registered"] == n
        idx = model.frame_index
        err = _truth_error(flight, idx, model.R, model.t)
        aligned = np.linalg.norm(err.alignment.apply(camera_centre(model.R, model.t))
                                 - np.stack([flight.cameras[i].center for i in idx]), axis=1)
        runs[joint] = (err.ate_rmse, float(np.sqrt(np.mean(aligned[pnp] ** 2))))
    path = np.linalg.norm(np.diff([c.center for c in flight.cameras], axis=0), axis=1).sum()
    assert runs[True][0] < 0.005 * path and runs[True][1] < 0.005 * path
    assert runs[True][0] <= runs[False][0] * 1.05 and runs[True][1] <= runs[False][1] * 1.05, runs
