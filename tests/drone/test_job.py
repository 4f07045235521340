"""The reconstruction job and the CLI verb: results on a generated video and a zip of stills,
and every bad input failing with a reason a person understands."""
import argparse
import io
import json
import zipfile

import av
import cv2
import numpy as np
import pytest

from workers.common.jobctx import JobInputError
from workers.drone import cli
from workers.drone.job import run_reconstruction
from workers.drone.pipeline import RESULT_NAMES
from workers.drone.params import ReconstructionParams
from workers.synth.flight import encode_video

from tests.fakectx import FakeContext

FAST = {"max_features": 1000}


def _intrinsics(flight):
    K = flight.K
    return {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}


def test_job_writes_all_results(tmp_path, flight):
    ctx = FakeContext(tmp_path, {**_intrinsics(flight), **FAST}, {"media": flight.path.read_bytes()})
    summary = run_reconstruction(ctx)
    for name in RESULT_NAMES:
        assert ctx.result_path(name).stat().st_size > 0, name
    report = json.loads(ctx.result_path("report.json").read_text())
    assert report["frames"]["registered"] == summary["frames_registered"] >= 30
    assert set(report["timings_s"]) >= {"decode", "track", "initialise", "register", "bundle_adjustment",
                                        "export", "preview"}
    assert cv2.imdecode(np.frombuffer(ctx.result_path("preview.png").read_bytes(), np.uint8), 1).shape[2] == 3
    traj = json.loads(ctx.result_path("trajectory.json").read_text())
    assert len(traj["frames"]) == report["frames"]["decoded"]  # every decoded frame, selected or not
    assert traj["counts"]["registered"] == report["frames"]["registered"] + report["frames"]["skipped_registered"]
    stages = [s for _, s in ctx.progress_calls]
    assert stages[0] == "decode" and stages[-1] == "done"
    assert any(s.startswith("track ") for s in stages) and any(s.startswith("BA iteration") for s in stages)


def test_job_reads_a_zip_of_stills_and_a_calibration_file(tmp_path, flight):
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for i, img in enumerate(flight.frames[::2]):
            zf.writestr(f"shots/img_{i}.png", cv2.imencode(".png", img)[1].tobytes())  # natural order: 2 < 10
        zf.writestr("shots/readme.txt", "not an image")
    K = flight.K
    calib = f"1 PINHOLE 320 240 {K[0, 0]} {K[1, 1]} {K[0, 2] + 0.5} {K[1, 2] + 0.5}\n"
    ctx = FakeContext(tmp_path, {"matcher": "sift", "max_features": 800},
                      {"media": buf.getvalue(), "calibration": calib.encode()})
    run_reconstruction(ctx)
    traj = json.loads(ctx.result_path("trajectory.json").read_text())
    assert [f["name"] for f in traj["frames"]] == [f"img_{i}.png" for i in range(18)]
    assert sum(f["registered"] for f in traj["frames"]) >= 16
    assert traj["intrinsics"]["cx"] == pytest.approx(K[0, 2])


def _fails(tmp_path, params, files, match):
    ctx = FakeContext(tmp_path, params, files)
    with pytest.raises(JobInputError, match=match):
        run_reconstruction(ctx)
    assert not any(ctx.result_path(n).exists() for n in RESULT_NAMES)


def test_bad_inputs_fail_with_a_reason(tmp_path, flight):
    video = flight.path.read_bytes()
    good = _intrinsics(flight)
    _fails(tmp_path / "a", good, {"media": b"this is plain text, not a video"}, "not a video")
    _fails(tmp_path / "b", {**good, "georeference": "required"}, {"media": video}, "no GPS positions")
    _fails(tmp_path / "c", {**good, "fx": 1e6, "fy": 1e6}, {"media": video}, "focal length .* implausible")
    _fails(tmp_path / "d", {**good, "cx": 5000.0}, {"media": video}, "principal point")
    _fails(tmp_path / "e", {**good, "fx": -3}, {"media": video}, "invalid parameters")
    _fails(tmp_path / "f", good, {}, "missing input 'media'")
    _fails(tmp_path / "g", {}, {"media": video, "calibration": b"\xff\xfe garbage"}, "calibration file is not text")
    _fails(tmp_path / "g2", {}, {"media": video, "calibration": b"hello"}, "could not read the calibration")
    empty = io.BytesIO()
    with zipfile.ZipFile(empty, "w") as zf:
        zf.writestr("notes.txt", "no images")
    _fails(tmp_path / "h", good, {"media": empty.getvalue()}, "holds no images")


def test_video_without_decodable_frames(tmp_path, flight):
    full = encode_video(flight.frames[:3], tmp_path / "v.mkv").read_bytes()
    # Matroska writes its header first: cut the file where the stream is declared but no frame follows.
    for cut in range(200, len(full), 20):
        (tmp_path / "cut.mkv").write_bytes(full[:cut])
        try:
            with av.open(str(tmp_path / "cut.mkv")) as c:
                if c.streams.video and sum(1 for _ in c.decode(video=0)) == 0:
                    break
        except av.error.FFmpegError:
            continue
    else:
        pytest.fail("no header-only cut found")
    _fails(tmp_path / "x", _intrinsics(flight), {"media": full[:cut]}, "no decodable frames")
    one = tmp_path / "one.mp4"
    encode_video(flight.frames[:1], one)
    _fails(tmp_path / "y", _intrinsics(flight), {"media": one.read_bytes()}, "at least two")


def test_a_camera_that_never_moves(tmp_path, flight):
    rng = np.random.default_rng(0)
    frames = [np.clip(flight.frames[0] + rng.normal(0, 2, flight.frames[0].shape), 0, 255).astype(np.uint8)
              for _ in range(20)]
    path = encode_video(frames, tmp_path / "still.mp4")
    for matcher in ("fast_lk", "sift"):
        _fails(tmp_path / matcher, {**_intrinsics(flight), "matcher": matcher, "frame_step": 1},
               {"media": path.read_bytes()}, "(never moves|does not move enough)")


def test_params_model_rejects_partial_intrinsics_and_unknown_fields():
    with pytest.raises(ValueError, match="all four"):
        ReconstructionParams(fx=500.0)
    with pytest.raises(ValueError):
        ReconstructionParams(bogus=1)
    with pytest.raises(ValueError, match="distortion"):
        ReconstructionParams(distortion=[0.1, 0.2, 0.3])


def _parser():
    parser = argparse.ArgumentParser()
    cli.register(parser.add_subparsers())
    return parser


def test_cli_reconstruct(tmp_path, flight, capsys):
    out = tmp_path / "rec"
    args = _parser().parse_args(["reconstruct", str(flight.path), "--intrinsics", flight.intrinsics, "--out", str(out),
                                 "--params", json.dumps(FAST)])
    assert args.func(args) == 0
    assert {p.name for p in out.iterdir()} >= set(RESULT_NAMES)
    assert "frames registered" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["--intrinsics", "1,2,3"], "four numbers"),
    (["--intrinsics", "a,b,c,d"], "comma-separated"),
    (["--georeference", "required"], "no GPS positions"),
    (["--intrinsics", "200,200,5000,100"], "principal point"),
])
def test_cli_bad_input_exits_2_with_a_message(tmp_path, flight, capsys, argv, message):
    args = _parser().parse_args(["reconstruct", str(flight.path), "--out", str(tmp_path / "o"), *argv])
    assert args.func(args) == 2
    err = capsys.readouterr().err
    assert message in err.strip().splitlines()[-1] and "Traceback" not in err
