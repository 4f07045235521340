"""Drone reconstruction over HTTP: a generated flight video end to end, and inputs a person gets wrong."""
from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest

from tests.app.test_jobs_e2e import wait_final
from workers.synth.flight import encode_video, flight_cameras, render_flight, terrain_scene


@pytest.fixture(scope="module")
def flight_video(tmp_path_factory):
    cams = flight_cameras(24, length=24.0, altitude=25.0, sway=3.0, width=320, height=240, fov_deg=70,
                          shake_deg=0.2, seed=4)
    frames = render_flight(terrain_scene(4, extent=80.0, n_buildings=10, n_trees=12), cams)
    path = encode_video(frames, tmp_path_factory.mktemp("flight") / "flight.mp4", fps=25)
    K = cams[0].K
    return path.read_bytes(), {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}


@pytest.fixture
def client(client_factory):
    return client_factory()


def test_a_flight_video_gives_cameras_points_and_a_report(client, flight_video):
    video, intrinsics = flight_video
    r = client.post("/v1/reconstructions", files={"media": ("flight.mp4", video, "video/mp4")},
                    data={"params": json.dumps({**intrinsics, "frame_step": 1})})
    assert r.status_code == 202, r.text
    job = wait_final(client, r.json()["id"], timeout=600)
    assert job["state"] == "succeeded", job
    names = {f["name"] for f in job["result"]["files"]}
    assert {"points.ply", "cameras.txt", "images.txt", "points3D.txt", "trajectory.json", "report.json",
            "preview.png"} <= names
    report = client.get(f"/v1/jobs/{job['id']}/results/report.json").json()
    assert report["frames"]["registered"] >= 20 and report["points"] > 200
    assert report["reprojection_error_px"]["after_ba"]["mean"] < 2.0
    ply = client.get(f"/v1/jobs/{job['id']}/results/points.ply").content
    assert ply.startswith(b"ply") and f"element vertex {report['points']}".encode() in ply[:400]
    trajectory = client.get(f"/v1/jobs/{job['id']}/results/trajectory.json").json()
    registered = [f for f in trajectory["frames"] if f["registered"]]
    # The report counts the selected frames; the trajectory also poses the frames selection left out.
    assert len(registered) == report["frames"]["registered"] + report["frames"]["skipped_registered"]
    assert len(trajectory["frames"]) == report["frames"]["decoded"]


def test_a_video_without_intrinsics_is_self_calibrated(client, flight_video):
    video, intrinsics = flight_video
    r = client.post("/v1/reconstructions", files={"media": ("flight.mp4", video, "video/mp4")},
                    data={"params": json.dumps({"frame_step": 1})})
    assert r.status_code == 202, r.text
    job = wait_final(client, r.json()["id"], timeout=600)
    assert job["state"] == "succeeded", job
    report = client.get(f"/v1/jobs/{job['id']}/results/report.json").json()
    lens = report["intrinsics"]
    # No EXIF in a video, no telemetry: a default field of view, refined by the bundle adjustment.
    assert lens["source"] == "default_fov" and lens["self_calibrated"] and lens["distortion"] is not None
    assert report["frames"]["registered"] >= 20
    assert report["georeference"]["georeferenced"] is False


def test_bad_parameters_are_refused_before_upload_is_queued(client, flight_video):
    video, _ = flight_video
    for params, field in (({"fx": -5, "fy": 500, "cx": 160, "cy": 120}, "fx"),
                          ({"gsd_cm": 5, "georeference": "off"}, "gsd_cm"),
                          ({"orthophoto": "yes please"}, "orthophoto")):
        r = client.post("/v1/reconstructions", files={"media": ("flight.mp4", video, "video/mp4")},
                        data={"params": json.dumps(params)})
        assert r.status_code == 422 and field in r.json()["detail"], r.text


@pytest.mark.parametrize("name,data,fragment", [
    ("notes.mp4", b"this is not a video, just text" * 100, "video"),
    ("stills.zip", None, "image"),
])
def test_unusable_media_fails_the_job_with_a_reason(client, name, data, fragment):
    if data is None:
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w") as z:
            z.writestr("readme.txt", "no images in here")
        data = buf.getvalue()
    r = client.post("/v1/reconstructions", files={"media": (name, data, "application/octet-stream")},
                    data={"params": json.dumps({"fx": 500, "fy": 500, "cx": 160, "cy": 120})})
    job = wait_final(client, r.json()["id"])
    assert job["state"] == "failed"
    assert fragment in job["error"].lower() and "internal error" not in job["error"]


def test_a_camera_that_never_moves_fails_with_no_parallax(client, tmp_path):
    frame = (np.random.default_rng(0).integers(0, 256, (240, 320, 3))).astype(np.uint8)
    path = encode_video([frame] * 20, tmp_path / "still.mp4", fps=25)
    r = client.post("/v1/reconstructions", files={"media": ("still.mp4", path.read_bytes(), "video/mp4")},
                    data={"params": json.dumps({"fx": 500, "fy": 500, "cx": 160, "cy": 120, "frame_step": 1})})
    job = wait_final(client, r.json()["id"], timeout=300)
    assert job["state"] == "failed"
    assert "internal error" not in job["error"]
    assert any(word in job["error"].lower() for word in ("parallax", "move", "motion")), job["error"]
