"""The whole pipeline on a short generated drone video, with both matchers, against the true
camera path; outputs (PLY, COLMAP text, trajectory, preview) read back."""
import json

import numpy as np
import pytest

from workers.drone.calibration import from_values
from workers.drone.evaluation import trajectory_error
from workers.drone.export import colmap_text, ply_bytes, trajectory
from workers.drone.geometry import camera_centre
from workers.drone.params import ReconstructionParams
from workers.drone.preview import render_preview
from workers.drone.reconstruction import reconstruct


def _check_against_truth(model, flight, max_ate_fraction):
    reg = model.registered
    assert reg.mean() > 0.9
    gt = [flight.cameras[i] for i in model.frame_index[reg]]
    Rg = np.stack([c.R for c in gt])
    Cg = np.stack([c.center for c in gt])
    err = trajectory_error(camera_centre(model.R[reg], model.t[reg]), Cg, model.R[reg], Rg)
    path = np.linalg.norm(np.diff(Cg, axis=0), axis=1).sum()
    assert err.ate_rmse < max_ate_fraction * path
    assert err.rotation_mean_deg < 0.5
    return err


@pytest.mark.parametrize("matcher", ["fast_lk", "sift"])
def test_pipeline_recovers_the_flight(flight, matcher):
    K = flight.K
    stages = []
    model = reconstruct(flight.path, from_values(K[0, 0], K[1, 1], K[0, 2], K[1, 2]),
                        ReconstructionParams(matcher=matcher, max_features=1000),
                        lambda f, s: stages.append((f, s)))
    _check_against_truth(model, flight, 0.01)
    rep = model.report
    assert rep["points"] > 300 and rep["frames"]["decoded"] == 36
    after = rep["reprojection_error_px"]["after_ba"]
    assert after["mean"] < 1.0 and after["mean"] <= rep["reprojection_error_px"]["before_ba"]["mean"] + 1e-9
    assert rep["matcher"]["inlier_ratio_mean"] > 0.5
    names = [s for _, s in stages]
    for stage in ("track 1/", "keyframes", "initialise", "register", "BA iteration", "localise"):
        assert any(n.startswith(stage) for n in names), stage
    fractions = [f for f, _ in stages]
    assert fractions == sorted(fractions) and 0.9 < fractions[-1] <= 1.0
    json.dumps(rep)  # JSON-able

    # Outputs.
    ply = ply_bytes(model.points, model.colors)
    head, _, body = ply.partition(b"end_header\n")
    assert f"element vertex {len(model.points)}".encode() in head and len(body) == 15 * len(model.points)
    texts = colmap_text(model)
    images = [ln for ln in texts["images.txt"].splitlines() if not ln.startswith("#")]  # 2D lines may be empty
    assert len(images) == 2 * int(model.registered.sum())
    pts = [ln.split() for ln in texts["points3D.txt"].splitlines() if ln and not ln.startswith("#")]
    assert len(pts) == len(model.points)
    # Every track element points at a 2D point of that image holding this point's id.
    points2d = {int(images[i].split()[0]): images[i + 1].split() for i in range(0, len(images), 2)}
    for row in pts[:50]:
        pid, track = int(row[0]), list(map(int, row[8:]))
        for img, idx in zip(track[::2], track[1::2]):
            assert int(points2d[img][3 * idx + 2]) == pid
    cam = texts["cameras.txt"].splitlines()[-1].split()
    assert cam[1] == "PINHOLE" and float(cam[6]) == pytest.approx(K[0, 2] + 0.5)
    traj = trajectory(model)
    assert [f["frame"] for f in traj["frames"]] == list(range(36))  # every decoded frame, in order
    selected = [f for f in traj["frames"] if f["selected"]]
    assert [f["frame"] for f in selected] == list(model.frame_index)
    assert sum(f["registered"] for f in selected) == int(model.registered.sum())
    assert traj["counts"]["registered"] == sum(f["registered"] for f in traj["frames"])
    img = render_preview(model.points, model.colors, model.R[model.registered], model.t[model.registered], 200)
    assert img.shape == (200, 600, 3) and (img != 40).any(axis=2).mean() > 0.02


def test_pipeline_with_a_frame_step_and_downscaling(flight):
    K = flight.K
    model = reconstruct(flight.path, from_values(K[0, 0], K[1, 1], K[0, 2], K[1, 2]),
                        ReconstructionParams(frame_step=2, max_width=240, max_features=600))
    assert list(model.frame_index) == list(range(0, 36, 2))
    assert model.width == 240 and model.scale == pytest.approx(0.75)
    _check_against_truth(model, flight, 0.02)
