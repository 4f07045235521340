"""The job functions (recording import, batch render, demo) on a fake job context."""
import json
import zipfile

import cv2
import numpy as np
import pytest

from harness.takes import png, rig_json, write_videos, zip_bytes
from tests.fakectx import FakeContext
from workers.camera import Camera
from workers.common.jobctx import JobInputError
from workers.streaming.demo import demo_rig, demo_scene
from workers.streaming.job import run_batch_render, run_demo_recording, run_recording_import
from workers.streaming.params import BatchRenderParams
from workers.streaming.recording import RecordingArchive
from workers.streaming.video import decode_frames, probe_video
from workers.synth import render


@pytest.fixture(scope="module")
def recording(take, tmp_path_factory):
    """A recording archive of the take, imported from image folders by the job."""
    root = tmp_path_factory.mktemp("import")
    ctx = FakeContext(root, {"rig_id": "r", "source": "images", "fps": 5.0},
                      {"rig": rig_json(take.rig), "archive": zip_bytes(take)})
    summary = run_recording_import(ctx)
    assert summary == {"frames": 3, "fps": 5.0, "cameras": 4, "background": "given"}
    assert [f for f, _ in ctx.progress_calls][-1] == 1.0
    return ctx.result_path("frames.zip")


def test_import_videos_with_background_images(take, tmp_path):
    paths = write_videos(take, tmp_path, names=["d", "c", "b", "a"])  # not named after the cameras: rig order
    files = {"rig": rig_json(take.rig), **{f"media-{i:03d}": p.read_bytes() for i, p in enumerate(paths)},
             **{f"background-{i:03d}": png(take.backgrounds[c]) for i, c in enumerate([3, 2, 1, 0])}}
    ctx = FakeContext(tmp_path / "job", {"rig_id": "r", "source": "videos", "cameras": [0, 1, 2, 3],
                                         "backgrounds": [3, 2, 1, 0]}, files,
                      input_meta={f"media-{i:03d}": {"filename": p.name} for i, p in enumerate(paths)})
    assert run_recording_import(ctx) == {"frames": 3, "fps": 10.0, "cameras": 4, "background": "given"}
    archive = RecordingArchive(ctx.result_path("frames.zip"))
    np.testing.assert_array_equal(archive.backgrounds()[3], take.backgrounds[3])
    np.testing.assert_array_equal(archive.frame_set(1)[2], list(decode_frames(paths[2]))[1])


def test_import_videos_of_different_lengths_fails_naming_them(take, tmp_path):
    paths = write_videos(take, tmp_path, frames=[3, 3, 3, 2])
    files = {"rig": rig_json(take.rig), **{f"media-{i:03d}": p.read_bytes() for i, p in enumerate(paths)}}
    ctx = FakeContext(tmp_path / "job", {"rig_id": "r", "source": "videos", "cameras": [0, 1, 2, 3]}, files,
                      input_meta={f"media-{i:03d}": {"filename": p.name} for i, p in enumerate(paths)})
    with pytest.raises(JobInputError, match=r"differ in length \(cam00.mp4: 3, cam01.mp4: 3, cam02.mp4: 3, cam03.mp4: 2"):
        run_recording_import(ctx)


def test_import_of_a_broken_zip_is_a_user_error(take, tmp_path):
    ctx = FakeContext(tmp_path, {"rig_id": "r", "source": "images"}, {"rig": rig_json(take.rig), "archive": b"PK nope"})
    with pytest.raises(JobInputError, match="not a zip"):
        run_recording_import(ctx)


def test_batch_render_writes_h264_and_depth_pngs(take, recording, tmp_path):
    params = BatchRenderParams(recording_id="r", orbit={"azimuth_from": -20, "azimuth_to": 20}, width=96, height=72,
                               frames=5, planes=32, fps=8).model_dump(mode="json")
    ctx = FakeContext(tmp_path, params, {"rig": rig_json(take.rig), "recording": recording.read_bytes()})
    summary = run_batch_render(ctx)
    assert summary["frames"] == 5 and summary["recording_frames"] == [0, 2]
    assert [round(f, 2) for f, _ in ctx.progress_calls] == [0.2, 0.4, 0.6, 0.8, 1.0]
    video = probe_video(ctx.result_path("video.mp4"))
    assert (video.frames, video.width, video.height, video.fps, video.codec) == (5, 96, 72, 8.0, "h264")
    with zipfile.ZipFile(ctx.result_path("depth.zip")) as zf:
        path = json.loads(zf.read("path.json"))
        assert path["frames"] == [0, 0, 1, 2, 2]  # frames 0..2 spread over 5 outputs
        depth = cv2.imdecode(np.frombuffer(zf.read("depth/000004.png"), np.uint8), cv2.IMREAD_UNCHANGED)
    assert depth.dtype == np.uint16 and depth.shape == (72, 96)
    last = Camera.from_dict(path["cameras"][4])
    truth = render(demo_scene(2 / 3), last, with_background=False)  # the take's frame 2
    found = (depth > 0) & truth.silhouette
    assert found.sum() > 0.5 * truth.silhouette.sum()
    error = np.abs(depth[found] / 1000.0 - truth.depth[found])
    assert np.median(error) < 0.1


def test_batch_render_refuses_frames_out_of_range(take, recording, tmp_path):
    params = BatchRenderParams(recording_id="r", orbit={}, frame_start=1, frame_end=7, width=32, height=24)
    ctx = FakeContext(tmp_path, params.model_dump(mode="json"),
                      {"rig": rig_json(take.rig), "recording": recording.read_bytes()})
    with pytest.raises(JobInputError, match="out of range: the recording has 3 frames"):
        run_batch_render(ctx)


def test_demo_job_renders_the_procedural_studio(tmp_path):
    rig = demo_rig(3, (48, 36))
    ctx = FakeContext(tmp_path, {"frames": 2, "fps": 4.0}, {"rig": rig_json(rig)})
    assert run_demo_recording(ctx) == {"frames": 2, "fps": 4.0, "cameras": 3, "background": "given"}
    archive = RecordingArchive(ctx.result_path("frames.zip"))
    first, second = archive.frame_set(0), archive.frame_set(1)
    assert np.abs(first[1].astype(int) - second[1]).max() > 50  # the small sphere moved
    np.testing.assert_array_equal(first[0], render(demo_scene(0.0), rig[0]).image)


def test_the_demo_job_keeps_its_recording_in_the_services_demo_cache(tmp_path, monkeypatch):
    """The service passes its demo cache to its workers: the next data folder's demo job copies it."""
    monkeypatch.setenv("SWEEPCAST_DEMO_CACHE_DIR", str(tmp_path / "cache"))
    rig = demo_rig(2, (32, 24))
    ctx = FakeContext(tmp_path / "job", {"frames": 2, "fps": 4.0}, {"rig": rig_json(rig)})
    run_demo_recording(ctx)
    assert [p.read_bytes() for p in (tmp_path / "cache").iterdir()] == [ctx.result_path("frames.zip").read_bytes()]
