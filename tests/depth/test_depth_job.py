import json

import cv2
import numpy as np
import pytest

from tests.fakectx import FakeContext
from workers.common.jobctx import JobInputError
from workers.depth import io
from workers.depth.methods import FilterOptions, postprocess
from workers.depth.job import run_depth_video


def frames(n=3, h=12, w=16, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        d = np.full((h, w), 30, np.uint8)
        d[3:9, 4 + i:10 + i] = 200
        out.append(np.clip(d.astype(int) + rng.integers(-2, 3, d.shape), 0, 255).astype(np.uint8))
    return out


def yuv_bytes(tmp_path, depth_frames, fmt):
    path = tmp_path / "src.yuv"
    io.write_yuv(path, depth_frames, fmt)
    return path.read_bytes()


def test_video_job_filters_every_frame(tmp_path):
    src = frames()
    data = yuv_bytes(tmp_path, src, io.YuvFormat(16, 12, 8, "420"))
    params = {"width": 16, "height": 12, "chroma": "420", "scale": 2, "method": "modified_morph",
              "upsampler": "bilinear", "z_near": 1.0, "z_far": 10.0}
    ctx = FakeContext(tmp_path / "job", params, {"depth": data})
    summary = run_depth_video(ctx)
    assert summary["frames"] == 3 and summary["output"] == {"width": 32, "height": 24, "bits": 8, "chroma": "420"}
    out = io.read_yuv(ctx.result_path("filtered.yuv"), io.YuvFormat(32, 24, 8, "420"))
    for got, frame in zip(out, src):
        np.testing.assert_array_equal(got, postprocess(frame, "modified_morph", scale=2, upsampler="bilinear"))
    assert [round(f, 3) for f, _ in ctx.progress_calls] == [0.333, 0.667, 1.0]
    report = json.loads(ctx.result_path("report.json").read_bytes())
    assert len(report["per_frame"]) == 3 and report["params"]["method"] == "modified_morph"
    assert 1.0 <= report["per_frame"][0]["nearest_m"] < report["per_frame"][0]["farthest_m"] <= 10.0


def test_video_job_sixteen_bit_target_size(tmp_path):
    src = [f.astype(np.uint16) * 4 for f in frames(2)]
    data = yuv_bytes(tmp_path, src, io.YuvFormat(16, 12, 10))
    ctx = FakeContext(tmp_path / "job", {"width": 16, "height": 12, "bits": 10, "out_width": 24, "out_height": 18,
                                         "method": "dilation"}, {"depth": data})
    run_depth_video(ctx)
    out = io.read_yuv(ctx.result_path("filtered.yuv"), io.YuvFormat(24, 18, 10))
    expected = postprocess(src[1], "dilation", size=(24, 18), options=FilterOptions(bits=10))
    np.testing.assert_array_equal(out[1], expected)


def test_video_job_with_texture_for_the_weighted_mode_filter(tmp_path):
    src = frames(2)
    data = yuv_bytes(tmp_path, src, io.YuvFormat(16, 12))
    tex = b"".join(cv2.cvtColor(np.full((24, 32, 3), 90, np.uint8), cv2.COLOR_BGR2YUV_I420).tobytes() for _ in src)
    params = {"width": 16, "height": 12, "scale": 2, "method": "wmf"}
    ctx = FakeContext(tmp_path / "job", params, {"depth": data, "texture": tex})
    assert run_depth_video(ctx)["frames"] == 2
    with pytest.raises(JobInputError, match="needs a 'texture' input"):
        run_depth_video(FakeContext(tmp_path / "job2", params, {"depth": data}))
    with pytest.raises(JobInputError, match="texture must hold 2 frames"):
        run_depth_video(FakeContext(tmp_path / "job3", params, {"depth": data, "texture": tex[:-10]}))


def test_video_job_bad_input(tmp_path):
    data = yuv_bytes(tmp_path, frames(2), io.YuvFormat(16, 12))
    with pytest.raises(JobInputError, match="not a whole number of 16x12 8-bit 4:0:0 frames"):
        run_depth_video(FakeContext(tmp_path / "a", {"width": 16, "height": 12}, {"depth": data[:-1]}))
    with pytest.raises(JobInputError, match="invalid parameters"):
        run_depth_video(FakeContext(tmp_path / "b", {"width": 16, "height": 12, "scale": 0}, {"depth": data}))
    with pytest.raises(JobInputError, match="invalid parameters"):
        run_depth_video(FakeContext(tmp_path / "c", {"width": 16, "height": 12, "method": "blur"}, {"depth": data}))
    with pytest.raises(JobInputError, match="frame 0 has level .* above the 10-bit maximum 1023"):
        run_depth_video(FakeContext(tmp_path / "d", {"width": 16, "height": 12, "bits": 10}, {"depth": data}))


def test_video_job_reads_a_coded_h264_depth_video(tmp_path):
    from workers.depth.video import decode_depth_video, encode_depth_frames

    src = frames(3, 12, 16)
    data = encode_depth_frames(src, "h264", 20, gop=3)
    decoded = list(decode_depth_video(data))
    params = {"input_format": "video", "scale": 2, "method": "modified_morph"}
    ctx = FakeContext(tmp_path / "job", params, {"depth": data})
    summary = run_depth_video(ctx)
    assert summary["frames"] == 3 and summary["input"]["codec"] == "h264"
    assert summary["input"]["width"] == 16 and summary["input"]["height"] == 12
    out = io.read_yuv(ctx.result_path("filtered.yuv"), io.YuvFormat(32, 24))
    for got, frame in zip(out, decoded):
        np.testing.assert_array_equal(got, postprocess(frame, "modified_morph", scale=2))


def test_video_job_refuses_a_video_with_too_many_frames_or_the_wrong_size(tmp_path, monkeypatch):
    from workers.depth.video import encode_depth_frames

    data = encode_depth_frames(frames(3, 12, 16), "h264", 30)
    with pytest.raises(JobInputError, match="width 20"):
        run_depth_video(FakeContext(tmp_path / "a", {"input_format": "video", "width": 20}, {"depth": data}))
    monkeypatch.setenv("SWEEPCAST_MAX_VIDEO_FRAMES", "2")
    with pytest.raises(JobInputError, match="more than 2 frames"):
        run_depth_video(FakeContext(tmp_path / "b", {"input_format": "video"}, {"depth": data}))
    with pytest.raises(JobInputError, match="is not a video"):
        run_depth_video(FakeContext(tmp_path / "c", {"input_format": "video"}, {"depth": b"\x00" * 500}))
