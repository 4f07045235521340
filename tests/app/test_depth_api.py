"""The depth routes over HTTP: filter, synthesise, the video job, and bad input."""
from __future__ import annotations

import base64
import json

import cv2
import numpy as np
import pytest

from tests.app.test_jobs_e2e import wait_final
from tests.depth.scene import Scene


def png(array: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", array)
    assert ok
    return buf.tobytes()


def square_depth(size=32, fg=200, bg=50) -> np.ndarray:
    depth = np.full((size, size), bg, np.uint8)
    depth[8:24, 8:24] = fg
    return depth


@pytest.fixture
def client(client_factory):
    return client_factory()


def test_filter_upsamples_and_dilates(client):
    r = client.post("/v1/depth/filter", files={"depth": ("d.png", png(square_depth()), "image/png")},
                    data={"params": json.dumps({"method": "dilation", "scale": 2, "window": 3})})
    assert r.status_code == 200, r.text
    out = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_UNCHANGED)
    assert out.shape == (64, 64) and out.dtype == np.uint8
    # Nearest x2 puts the square at [16, 48); a 3x3 dilation grows it by one pixel each side.
    assert out[15, 30] == 200 and out[14, 30] == 50 and out[48, 30] == 200 and out[49, 30] == 50


def test_filter_keeps_16_bit_maps_16_bit(client):
    depth = (square_depth().astype(np.uint16) * 257)
    r = client.post("/v1/depth/filter", files={"depth": ("d.png", png(depth), "image/png")},
                    data={"params": json.dumps({"method": "modified_morph"})})
    assert r.status_code == 200, r.text
    out = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_UNCHANGED)
    assert out.dtype == np.uint16 and out.max() == 200 * 257


@pytest.mark.parametrize("params,fragment", [
    ({"method": "median"}, "method"),
    ({"scale": 0}, "scale"),
    ({"window": 4}, "odd"),
])
def test_bad_filter_parameters_are_422_naming_the_field(client, params, fragment):
    r = client.post("/v1/depth/filter", files={"depth": ("d.png", png(square_depth()), "image/png")},
                    data={"params": json.dumps(params)})
    assert r.status_code == 422 and r.json()["error"] == "invalid_parameters"
    assert fragment in r.json()["detail"]


def test_params_that_are_not_json_are_422(client):
    r = client.post("/v1/depth/filter", files={"depth": ("d.png", png(square_depth()), "image/png")},
                    data={"params": "{method: dilation"})
    assert r.status_code == 422 and "JSON" in r.json()["detail"]


def test_wrong_bit_depth_and_mismatched_texture_are_400(client):
    r = client.post("/v1/depth/filter", files={"depth": ("d.png", png(square_depth()), "image/png")},
                    data={"params": json.dumps({"bits": 16})})
    assert r.status_code == 400 and "16" in r.json()["detail"]
    texture = np.zeros((10, 10, 3), np.uint8)
    r = client.post("/v1/depth/filter",
                    files={"depth": ("d.png", png(square_depth()), "image/png"),
                           "texture": ("t.png", png(texture), "image/png")},
                    data={"params": json.dumps({"method": "wmf", "scale": 2})})
    assert r.status_code == 400 and r.json()["error"] == "bad_depth_input"


def test_synthesis_reproduces_the_target_where_visible(client):
    scene = Scene()
    (tex0, disp0), (tex2, disp2), (target, _) = scene.render(0), scene.render(2), scene.render(1)
    files = [("textures", ("t0.png", png(tex0), "image/png")), ("textures", ("t2.png", png(tex2), "image/png")),
             ("depths", ("d0.png", png(disp0.astype(np.uint8)), "image/png")),
             ("depths", ("d2.png", png(disp2.astype(np.uint8)), "image/png"))]
    params = {"depth_units": "disparity", "positions": [0, 2], "target_position": 1, "boundary_width": 0}
    r = client.post("/v1/depth/synthesize", files=files, data={"params": json.dumps(params)})
    assert r.status_code == 200, r.text
    body = r.json()
    image = cv2.imdecode(np.frombuffer(base64.b64decode(body["image_png"]), np.uint8), cv2.IMREAD_COLOR)
    holes = cv2.imdecode(np.frombuffer(base64.b64decode(body["holes_png"]), np.uint8), cv2.IMREAD_GRAYSCALE)
    seen = (scene.visible_from(0, 1) | scene.visible_from(2, 1)) & (holes == 0)
    assert seen.mean() > 0.8
    assert np.array_equal(image[seen], target[seen])


def test_synthesis_with_mismatched_view_counts_is_refused(client):
    tex = png(np.zeros((8, 8, 3), np.uint8))
    params = {"depth_units": "disparity", "positions": [0, 2], "target_position": 1}
    r = client.post("/v1/depth/synthesize", files=[("textures", ("a.png", tex, "image/png")),
                                                   ("depths", ("a.png", tex, "image/png")),
                                                   ("depths", ("b.png", tex, "image/png"))],
                    data={"params": json.dumps(params)})
    assert r.status_code == 422


def test_video_job_filters_every_frame(client):
    frames = np.stack([np.roll(square_depth(), i, axis=1) for i in range(5)])
    params = {"width": 32, "height": 32, "method": "modified_morph", "scale": 2}
    r = client.post("/v1/depth/videos", files={"depth": ("seq.yuv", frames.tobytes(), "application/octet-stream")},
                    data={"params": json.dumps(params)})
    assert r.status_code == 202, r.text
    job = wait_final(client, r.json()["id"])
    assert job["state"] == "succeeded", job
    out = client.get(f"/v1/jobs/{job['id']}/results/filtered.yuv").content
    assert len(out) == 5 * 64 * 64
    report = client.get(f"/v1/jobs/{job['id']}/results/report.json").json()
    assert report["frames"] == 5


def test_yuv_that_is_not_whole_frames_is_refused_at_upload(client):
    params = {"width": 32, "height": 32}
    r = client.post("/v1/depth/videos", files={"depth": ("seq.yuv", b"\x00" * (32 * 32 * 2 + 7), "application/octet-stream")},
                    data={"params": json.dumps(params)})
    assert r.status_code == 422 and r.json()["error"] == "bad_depth_input"
    assert client.get("/v1/jobs", params={"kind": "depth.video"}).json()["jobs"] == []


def h264_depth_video(frames) -> bytes:
    from workers.depth.video import encode_depth_frames

    return encode_depth_frames(list(frames), "h264", 20, gop=len(frames))


def test_video_job_accepts_a_coded_h264_depth_video(client):
    from workers.depth.methods import postprocess
    from workers.depth.video import decode_depth_video

    frames = [np.roll(square_depth(), i, axis=1) for i in range(4)]
    data = h264_depth_video(frames)
    params = {"input_format": "video", "method": "dilation", "scale": 2}
    r = client.post("/v1/depth/videos", files={"depth": ("seq.264", data, "video/h264")},
                    data={"params": json.dumps(params)})
    assert r.status_code == 202, r.text
    job = wait_final(client, r.json()["id"])
    assert job["state"] == "succeeded", job
    out = np.frombuffer(client.get(f"/v1/jobs/{job['id']}/results/filtered.yuv").content, np.uint8)
    out = out.reshape(4, 64, 64)
    for got, frame in zip(out, decode_depth_video(data)):
        np.testing.assert_array_equal(got, postprocess(frame, "dilation", scale=2))
    report = client.get(f"/v1/jobs/{job['id']}/results/report.json").json()
    assert report["frames"] == 4 and report["input"]["codec"] == "h264"


@pytest.mark.parametrize("make,status,error", [
    (lambda: b"certainly not a video" * 20, 415, "not_a_video"),
    (lambda: b"", 400, "empty_file"),
])
def test_depth_video_that_is_not_a_video_is_refused_at_upload(client, make, status, error):
    r = client.post("/v1/depth/videos", files={"depth": ("seq.264", make(), "video/h264")},
                    data={"params": json.dumps({"input_format": "video"})})
    assert r.status_code == status, r.text
    assert r.json()["error"] == error and r.json()["detail"]
    assert client.get("/v1/jobs", params={"kind": "depth.video"}).json()["jobs"] == []


def test_depth_video_limits_come_from_settings(client_factory):
    small = client_factory(max_video_frames=2, max_image_pixels=2000)
    data = h264_depth_video([square_depth()] * 3)
    r = small.post("/v1/depth/videos", files={"depth": ("seq.264", data, "video/h264")},
                   data={"params": json.dumps({"input_format": "video"})})
    assert r.status_code == 413 and r.json()["error"] == "too_many_frames"
    r = small.post("/v1/depth/videos", files={"depth": ("seq.264", h264_depth_video([square_depth(64)]), "video/h264")},
                   data={"params": json.dumps({"input_format": "video"})})
    assert r.status_code == 413 and r.json()["error"] == "too_many_pixels"
    r = small.post("/v1/depth/videos", files={"depth": ("seq.264", h264_depth_video([square_depth()]), "video/h264")},
                   data={"params": json.dumps({"input_format": "video", "scale": 4})})
    assert r.status_code == 422 and r.json()["error"] == "output_too_large"


def test_yuv_without_its_size_is_422(client):
    r = client.post("/v1/depth/videos", files={"depth": ("seq.yuv", b"\x00" * 64, "application/octet-stream")},
                    data={"params": json.dumps({})})
    assert r.status_code == 422 and "width and height" in r.json()["detail"]


def wmf_request(size: int) -> dict:
    """A wmf request: a size/2 depth map upsampled x2 onto a size x size texture."""
    rng = np.random.default_rng(1)
    texture = cv2.resize(rng.integers(0, 256, (8, 8, 3), np.uint8), (size, size), interpolation=cv2.INTER_NEAREST)
    return {"files": {"depth": ("d.png", png(square_depth(size // 2)), "image/png"),
                      "texture": ("t.png", png(texture), "image/png")},
            "data": {"params": json.dumps({"method": "wmf", "scale": 2})}}


def test_filter_answers_exactly_what_the_engine_computes(client):
    from workers.depth.encoded import filter_depth_bytes
    from workers.depth.params import DepthFilterParams

    req = wmf_request(64)
    r = client.post("/v1/depth/filter", **req)
    assert r.status_code == 200, r.text
    expected = filter_depth_bytes(req["files"]["depth"][1], DepthFilterParams(method="wmf", scale=2),
                                  req["files"]["texture"][1])
    assert r.content == expected


def test_sync_work_over_the_cpu_limit_is_413_naming_the_job_route(client_factory):
    # wmf on 256x256 is estimated at ~0.04 CPU-s, dilation at ~0.001 s
    client = client_factory(sync_max_cpu_seconds=0.01)
    r = client.post("/v1/depth/filter", **wmf_request(256))
    assert r.status_code == 413 and r.json()["error"] == "too_much_work"
    detail = r.json()["detail"]
    assert "wmf on a 256x256 output" in detail and "CPU-seconds" in detail and "/v1/depth/videos" in detail
    cheap = wmf_request(256)
    cheap["data"] = {"params": json.dumps({"method": "dilation", "scale": 2})}
    del cheap["files"]["texture"]
    assert client.post("/v1/depth/filter", **cheap).status_code == 200


def test_sync_work_over_the_memory_limit_is_413(client_factory):
    client = client_factory(sync_max_memory_mb=1.0)  # wmf holds ~28 bytes per output pixel: 1.8 MB at 256x256
    r = client.post("/v1/depth/filter", **wmf_request(256))
    assert r.status_code == 413 and r.json()["error"] == "too_much_work" and "memory" in r.json()["detail"]
    assert client.post("/v1/depth/filter", **wmf_request(128)).status_code == 200  # 0.46 MB
    scene = Scene()
    (tex0, disp0), (tex2, disp2) = scene.render(0), scene.render(2)
    files = [("textures", ("t0.png", png(tex0), "image/png")), ("textures", ("t2.png", png(tex2), "image/png")),
             ("depths", ("d0.png", png(disp0.astype(np.uint8)), "image/png")),
             ("depths", ("d2.png", png(disp2.astype(np.uint8)), "image/png"))]
    params = {"depth_units": "disparity", "positions": [0, 2], "target_position": 1,
              "geometry": "rectified"}
    small = client_factory(sync_max_memory_mb=0.01)
    r = small.post("/v1/depth/synthesize", files=files, data={"params": json.dumps(params)})
    assert r.status_code == 413 and r.json()["error"] == "too_much_work"
    assert "synthesis of a" in r.json()["detail"] and "smaller view" in r.json()["detail"]


def test_sync_work_waits_for_room_then_is_503_with_retry_after(client_factory):
    from workers.common.work import WorkEstimate

    client = client_factory(sync_memory_budget_mb=4.0, sync_wait_seconds=0.2)
    gate = client.app.state.services.sync_work
    held = gate.admit(WorkEstimate(8.0, 4 * 2**20))  # another request holding the whole budget for ~8 CPU-s
    client.portal.call(held.__aenter__)
    try:
        r = client.post("/v1/depth/filter", **wmf_request(64))
        assert r.status_code == 503 and r.json()["error"] == "busy"
        assert int(r.headers["Retry-After"]) >= 1
    finally:
        client.portal.call(held.__aexit__, None, None, None)
    assert client.post("/v1/depth/filter", **wmf_request(64)).status_code == 200
