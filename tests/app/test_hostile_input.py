"""Hostile input over HTTP: every answer is a 4xx with the JSON error body, never a 500, and no
request makes the service decode, allocate or read more than its limits allow."""
from __future__ import annotations

import asyncio
import json
import logging
import socket
import struct
import threading
import time

import cv2
import numpy as np
import pytest

from tests.common.hostile import jpeg_declaring, png_bomb, zip_with
from tests.orientation.builders import insert_app1, jpeg, tiff_block


def png(array: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", array)
    assert ok
    return buf.tobytes()


def assert_error(r, status: int, code: str | None = None) -> dict:
    assert r.status_code == status, r.text
    body = r.json()
    assert set(body) >= {"error", "detail"} and isinstance(body["detail"], str)
    if code is not None:
        assert body["error"] == code, body
    return body


def synth_files(texture: bytes, depth: bytes) -> list:
    return [("textures", ("t.png", texture, "image/png")), ("depths", ("d.png", depth, "image/png"))]


SYNTH_PARAMS = json.dumps({"depth_units": "disparity", "positions": [0], "target_position": 1})


@pytest.fixture
def client(client_factory):
    return client_factory()


# --- 1. one pixel-limit-checked decoder ---------------------------------------------------------
def test_empty_image_part_is_a_400_on_the_depth_routes(client):
    r = client.post("/v1/depth/filter", files={"depth": ("d.png", b"", "image/png")})
    assert "empty" in assert_error(r, 400, "empty_file")["detail"]
    r = client.post("/v1/depth/synthesize", files=synth_files(b"", png(np.zeros((8, 8), np.uint8))),
                    data={"params": SYNTH_PARAMS})
    assert_error(r, 400, "empty_file")


def test_jpeg_declaring_65000_square_is_refused_undecoded(client):
    huge = jpeg_declaring(65000, 65000)
    r = client.post("/v1/depth/filter", files={"depth": ("d.jpg", huge, "image/jpeg")})
    assert "65000x65000" in assert_error(r, 413, "too_many_pixels")["detail"]
    r = client.post("/v1/depth/synthesize", files=synth_files(huge, png(np.zeros((8, 8), np.uint8))),
                    data={"params": SYNTH_PARAMS})
    assert_error(r, 413, "too_many_pixels")


def test_png_bomb_is_refused_by_depth_and_photo_routes_alike(client_factory):
    client = client_factory(max_image_pixels=50_000_000)
    bomb = png_bomb(7900, 7900)  # 62.4 megapixels in about 60 kB
    assert len(bomb) < 100_000
    for r in (client.post("/v1/depth/filter", files={"depth": ("d.png", bomb, "image/png")}),
              client.post("/v1/depth/synthesize", files=synth_files(png(np.zeros((8, 8, 3), np.uint8)), bomb),
                          data={"params": SYNTH_PARAMS}),
              client.post("/v1/photos/orientation", files={"file": ("p.png", bomb, "image/png")})):
        assert "50,000,000" in assert_error(r, 413, "too_many_pixels")["detail"]


# --- 2. output sizes and the compute pool -------------------------------------------------------
def test_depth_output_size_is_checked_against_the_pixel_limit(client_factory):
    client = client_factory(max_image_pixels=10_000)
    tiny = png(np.full((8, 8), 100, np.uint8))
    r = client.post("/v1/depth/filter", files={"depth": ("d.png", tiny, "image/png")},
                    data={"params": json.dumps({"out_width": 16384, "out_height": 16384})})
    body = assert_error(r, 422, "output_too_large")
    assert "16384x16384" in body["detail"] and "10,000" in body["detail"]
    r = client.post("/v1/depth/filter", files={"depth": ("d.png", tiny, "image/png")},
                    data={"params": json.dumps({"scale": 16})})  # 128 x 128 = 16,384 pixels
    assert "128x128" in assert_error(r, 422, "output_too_large")["detail"]
    r = client.post("/v1/depth/filter", files={"depth": ("d.png", tiny, "image/png")},
                    data={"params": json.dumps({"scale": 8})})  # 64 x 64: within the limit
    assert r.status_code == 200, r.text
    camera = {"K": [[10, 0, 4], [0, 10, 4], [0, 0, 1]]}
    params = {"geometry": "general", "z_near": 1, "z_far": 10, "cameras": [camera],
              "target_camera": {**camera, "width": 20000, "height": 20000}}
    r = client.post("/v1/depth/synthesize", files=synth_files(png(np.zeros((8, 8, 3), np.uint8)), tiny),
                    data={"params": json.dumps(params)})
    assert "20000x20000" in assert_error(r, 422, "output_too_large")["detail"]


def test_depth_and_face_work_runs_on_the_bounded_compute_pool(client, monkeypatch):
    from app.routers import depth, faces

    threads: list[str] = []

    def recording(real):
        def run(*args, **kwargs):
            threads.append(threading.current_thread().name)
            return real(*args, **kwargs)
        return run

    monkeypatch.setattr(depth, "filter_depth_bytes", recording(depth.filter_depth_bytes))
    monkeypatch.setattr(depth, "synthesize_bytes", recording(depth.synthesize_bytes))
    monkeypatch.setattr(faces, "transform_mesh_bytes", recording(faces.transform_mesh_bytes))
    tiny = png(np.full((8, 8), 100, np.uint8))
    assert client.post("/v1/depth/filter", files={"depth": ("d.png", tiny, "image/png")}).status_code == 200
    r = client.post("/v1/depth/synthesize", files=synth_files(png(np.zeros((8, 8, 3), np.uint8)), tiny),
                    data={"params": SYNTH_PARAMS})
    assert r.status_code == 200, r.text
    r = client.post("/v1/face-models/default/transform", files={"mesh": ("f.obj", b"v 0 0 0\n", "text/plain")},
                    data={"params": json.dumps({"impression": "smile_open"})})
    assert r.status_code == 422, r.text  # not a registered face; it still went through the pool
    assert len(threads) == 3 and all(name.startswith("compute") for name in threads), threads


# --- 3. bounded integers ------------------------------------------------------------------------
def test_offset_past_a_64_bit_integer_is_a_422(client):
    r = client.get("/v1/jobs", params={"offset": "9223372036854775808"})
    assert "offset" in assert_error(r, 422, "invalid_request")["detail"]
    assert client.get("/v1/jobs", params={"offset": 1_000_000_000}).json()["jobs"] == []


def test_every_integer_parameter_of_every_route_is_bounded(client):
    """Query, path and form integers all carry a minimum and a maximum in the app's own schema."""
    doc = client.get("/openapi.json").json()
    schemas = doc["components"]["schemas"]
    unbounded = []

    def check(where: str, schema: dict) -> None:
        options = schema.get("anyOf", [schema])
        for s in options:
            if s.get("type") == "integer" and not ({"minimum", "exclusiveMinimum"} & set(s)
                                                   and {"maximum", "exclusiveMaximum"} & set(s)):
                unbounded.append(where)

    for path, ops in doc["paths"].items():
        for method, op in ops.items():
            for param in op.get("parameters", []):
                check(f"{method.upper()} {path} {param['name']}", param.get("schema", {}))
            form = op.get("requestBody", {}).get("content", {}).get("multipart/form-data", {}).get("schema", {})
            ref = form.get("$ref", "").rsplit("/", 1)[-1]
            for name, prop in schemas.get(ref, {}).get("properties", {}).items():
                check(f"{method.upper()} {path} form {name}", prop)
    assert not unbounded


# --- 4. body limits per route -------------------------------------------------------------------
def test_oversize_json_body_is_a_413_at_once(client_factory):
    client = client_factory(max_json_bytes=1000)
    body = json.dumps({"recording_id": "x" * 5000}).encode()
    started = time.monotonic()
    r = client.post("/v1/rigs/no-such-rig/renders", content=body, headers={"content-type": "application/json"})
    assert "1000" in assert_error(r, 413, "payload_too_large")["detail"]  # before the route looks for the rig
    assert time.monotonic() - started < 2.0

    def chunks():
        for _ in range(50):
            yield b" " * 100

    r = client.post("/v1/rigs/no-such-rig/renders", content=chunks(), headers={"content-type": "application/json"})
    assert_error(r, 413, "payload_too_large")


def test_single_file_routes_get_the_upload_limit_and_batches_the_batch_limit(client_factory):
    client = client_factory(max_upload_bytes=2000, max_batch_bytes=100_000, max_json_bytes=500)
    big = b"v 0 0 0\n" * 1000  # 8000 bytes
    r = client.post("/v1/face-models/default/transform", files={"mesh": ("f.obj", big, "text/plain")},
                    data={"params": json.dumps({"impression": "smile_open"})})
    assert "2000" in assert_error(r, 413, "payload_too_large")["detail"]
    r = client.post("/v1/face-models", files={"dataset": ("d.zip", big, "application/zip")},
                    data={"params": json.dumps({"source": "synthetic"})})
    assert_error(r, 422, "invalid_request")  # read in full: the batch limit applies, not the upload limit


# --- 5. the API key before the body -------------------------------------------------------------
def test_without_a_key_the_body_is_never_read(settings_factory):
    from app.main import create_app

    app = create_app(settings_factory(api_keys=["s3cret"]))
    reads = 0
    sent: list[dict] = []

    async def receive() -> dict:
        nonlocal reads
        reads += 1
        return {"type": "http.request", "body": b"\0" * 65536, "more_body": True}

    async def send(message: dict) -> None:
        sent.append(message)

    scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1", "method": "POST", "scheme": "http",
             "path": "/v1/photos/batches", "raw_path": b"/v1/photos/batches", "root_path": "", "query_string": b"",
             "headers": [(b"host", b"test"), (b"content-length", b"200000000"),
                         (b"content-type", b"multipart/form-data; boundary=x")],
             "client": ("127.0.0.1", 1), "server": ("test", 80), "state": {}}
    asyncio.run(app(scope, receive, send))
    assert reads == 0
    assert sent[0]["status"] == 401
    assert json.loads(sent[1]["body"])["error"] == "unauthorized"


def test_a_real_server_answers_401_before_a_declared_200_mb_body_arrives(settings_factory):
    import uvicorn

    from app.logredact import RedactQuerySecrets
    from app.main import create_app

    app = create_app(settings_factory(api_keys=["s3cret"]))
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    server = uvicorn.Server(uvicorn.Config(app, lifespan="off", log_level="warning"))
    # uvicorn's logging set-up (in Config) keeps the redaction filter create_app installed
    assert any(isinstance(f, RedactQuerySecrets) for f in logging.getLogger("uvicorn.access").filters)
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    try:
        while not server.started:
            time.sleep(0.02)
        with socket.create_connection(sock.getsockname(), timeout=10) as conn:
            conn.sendall(b"POST /v1/photos/batches HTTP/1.1\r\nHost: x\r\nContent-Length: 200000000\r\n"
                         b"Content-Type: multipart/form-data; boundary=x\r\n\r\n--x\r\n"
                         b'Content-Disposition: form-data; name="files"; filename="a.jpg"\r\n\r\n' + b"\0" * 1000)
            reply = conn.recv(65536)  # the 199,999,000 other bytes are never sent
        assert reply.startswith(b"HTTP/1.1 401"), reply[:200]
        assert b'"unauthorized"' in reply
    finally:
        server.should_exit = True
        thread.join(10)


# --- 6. zip archives ----------------------------------------------------------------------------
RIG = {"cameras": [{"name": n, "K": [[100, 0, 16], [0, 100, 12], [0, 0, 1]], "R": np.eye(3).tolist(),
                    "t": [x, 0, 5], "width": 32, "height": 24} for n, x in (("a", 0.0), ("b", 0.5))]}


def test_recording_archive_that_is_a_zip_bomb_is_a_422(client):
    r = client.post("/v1/rigs", files={"files": ("rig.json", json.dumps(RIG).encode(), "application/json")})
    assert r.status_code == 201, r.text
    rig_id = r.json()["id"]
    bomb = zip_with(("a/0001.png", b"\0" * (64 << 20)))  # 64 MiB of zeros in about 64 kB
    r = client.post(f"/v1/rigs/{rig_id}/recordings", files={"archive": ("take.zip", bomb, "application/zip")})
    detail = assert_error(r, 422, "invalid_recording")["detail"]
    assert "take.zip" in detail and "expands" in detail
    evil = zip_with(("../a/0001.png", png(np.zeros((24, 32, 3), np.uint8))))
    r = client.post(f"/v1/rigs/{rig_id}/recordings", files={"archive": ("take.zip", evil, "application/zip")})
    assert "'..'" in assert_error(r, 422, "invalid_recording")["detail"]


# --- 7. secrets in the logs ---------------------------------------------------------------------
def test_access_token_is_redacted_in_uvicorn_logs(settings_factory):
    from app.main import create_app

    create_app(settings_factory())
    lines: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda record: lines.append(record.getMessage())  # type: ignore[method-assign]
    loggers = [logging.getLogger(name) for name in ("uvicorn.access", "uvicorn.error")]
    for logger in loggers:  # uvicorn's own set-up stops propagation: listen on the loggers themselves
        logger.addHandler(handler)
    try:
        # warning: above any level a logging set-up leaves on these loggers
        loggers[0].warning('%s - "%s %s HTTP/%s" %d', "127.0.0.1:5000", "GET",
                           "/v1/jobs/j1/events?access_token=s3cret&x=1", "1.1", 101)
        loggers[1].warning('%s - "WebSocket %s" [accepted]', "127.0.0.1:5000",
                           "/v1/rigs/r/live?view=1&ACCESS_TOKEN=s3cret")
    finally:
        for logger in loggers:
            logger.removeHandler(handler)
    assert lines == ['127.0.0.1:5000 - "GET /v1/jobs/j1/events?access_token=***&x=1 HTTP/1.1" 101',
                     '127.0.0.1:5000 - "WebSocket /v1/rigs/r/live?view=1&ACCESS_TOKEN=***" [accepted]']


# --- 8. non-finite numbers ----------------------------------------------------------------------
def test_nan_and_infinity_are_refused_in_every_schema(client):
    r = client.post("/v1/depth/synthesize", files=synth_files(png(np.zeros((8, 8, 3), np.uint8)),
                                                              png(np.zeros((8, 8), np.uint8))),
                    data={"params": '{"depth_units": "disparity", "positions": [NaN, 1], "target_position": 1}'})
    assert "finite" in assert_error(r, 422, "invalid_parameters")["detail"]
    r = client.post("/v1/depth/filter", files={"depth": ("d.png", png(np.zeros((8, 8), np.uint8)), "image/png")},
                    data={"params": '{"method": "wmf", "sigma_color": Infinity}'})
    assert_error(r, 422, "invalid_parameters")
    r = client.post("/v1/reconstructions", files={"media": ("v.mp4", b"\0" * 100, "video/mp4")},
                    data={"params": '{"fx": Infinity, "fy": 700, "cx": NaN, "cy": 400}'})
    assert_error(r, 422, "invalid_parameters")
    for bad in ({"K": [[float("inf"), 0, 16], [0, 100, 12], [0, 0, 1]]}, {"K": [[100, 0, float("nan")], [0, 100, 12],
                                                                                  [0, 0, 1]]}):
        rig = {"cameras": [{**RIG["cameras"][0], **bad}, RIG["cameras"][1]]}
        r = client.post("/v1/rigs", files={"files": ("rig.json", json.dumps(rig).encode(), "application/json")})
        assert "NaN or infinity" in assert_error(r, 422, "invalid_rig")["detail"]


def test_request_models_refuse_non_finite_floats():
    from workers.depth.params import CameraModel, DepthFilterParams, DepthVideoParams, SynthesizeParams
    from workers.faces.job import FaceTrainParams, FaceTransformParams
    from tests.common.test_registry import all_kinds

    models = {k.params for k in all_kinds()} | {DepthFilterParams, SynthesizeParams, CameraModel,
                                                          FaceTransformParams, FaceTrainParams, DepthVideoParams}
    lenient = [m.__name__ for m in models if m.model_config.get("allow_inf_nan", True)]
    assert not lenient


# --- 9. no server paths, no invalid tags --------------------------------------------------------
def test_calibration_errors_name_the_clients_file_not_a_temp_path(client):
    r = client.post("/v1/rigs", files={"files": ("my-rig.json", b"{not json", "application/json")})
    detail = assert_error(r, 422, "invalid_rig")["detail"]
    assert "my-rig.json" in detail and "/tmp" not in detail and "sweepcast-rig-" not in detail


def test_an_invalid_stored_orientation_is_never_echoed(client):
    photo = insert_app1(jpeg(), tiff_block([(274, 3, 1, struct.pack("<H", 99) + b"\0\0")]))
    r = client.post("/v1/photos/orient", files={"file": ("p.jpg", photo, "image/jpeg")})
    assert r.status_code == 200, r.text
    assert r.headers["X-Orientation"] in {*map(str, range(1, 9)), "none"}
    r = client.post("/v1/photos/orientation", files={"file": ("p.jpg", photo, "image/jpeg")})
    report = r.json()
    assert report["existing_orientation"] is None and report["file_orientation"] is None
    assert "99" in report["exif_detail"] and "not valid" in report["exif_detail"]


# --- 9. a full disk -----------------------------------------------------------------------------
def test_a_full_disk_refuses_uploads_with_507_and_keeps_nothing(client, monkeypatch):
    import errno
    import shutil as shutil_module
    from collections import namedtuple

    from harness.photos import noise_jpeg

    svc = client.app.state.services
    files = [("files", ("a.jpg", noise_jpeg(1), "image/jpeg")), ("files", ("b.jpg", noise_jpeg(2), "image/jpeg"))]
    written = []

    def full_after_one(key, data):
        if written:
            raise OSError(errno.ENOSPC, "No space left on device")
        written.append(key)
        return 1

    monkeypatch.setattr(svc.store, "put", full_after_one)  # the disk fills during the batch
    r = client.post("/v1/photos/batches", files=files)
    assert r.status_code == 507 and r.json()["error"] == "storage_full", r.text
    assert client.get("/v1/jobs").json()["jobs"] == []  # no job, and its first input was removed again
    monkeypatch.undo()
    assert svc.store.list("jobs") == []

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil_module, "disk_usage", lambda path: usage(10**9, 10**9, 10 * 2**20))  # 10 MB left
    ready = client.get("/readyz")
    assert ready.status_code == 503 and not ready.json()["checks"]["storage"]["ok"]
    assert "10 MB free" in ready.json()["checks"]["storage"]["detail"]
    r = client.post("/v1/photos/batches", files=files)
    assert r.status_code == 507 and "nearly full" in r.json()["detail"] and svc.store.list("jobs") == []
    assert client.get("/v1/jobs").status_code == 200  # reads keep working


# --- 10. slow clients ---------------------------------------------------------------------------
@pytest.mark.parametrize("pace, chunks, gap, expected", [
    ((0.2, 60.0, 0.0), 3, 0.5, "no part of the request body arrived for 0 s"),   # a stalled upload
    ((10.0, 0.3, 1000.0), 20, 0.05, "bytes/s, under the 1,000 bytes/s"),          # a trickle
])
def test_a_stalled_or_trickling_body_is_cut_off_with_408(pace, chunks, gap, expected):
    from app.limits import BodyLimitMiddleware, BodyPace

    sent = []

    async def app(scope, receive, send):
        while (await receive()).get("more_body"):
            pass
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b""})

    async def receive():
        await asyncio.sleep(gap)
        return {"type": "http.request", "body": b"x", "more_body": True}

    async def send(message):
        sent.append(message)

    scope = {"type": "http", "method": "POST", "path": "/v1/photos/orientation", "headers": []}
    middleware = BodyLimitMiddleware(app, limit_for=lambda scope: 10**6, pace=BodyPace(*pace))
    asyncio.run(asyncio.wait_for(middleware(scope, receive, send), 10))
    assert sent[0]["status"] == 408
    body = json.loads(sent[1]["body"])
    assert body["error"] == "upload_too_slow" and expected in body["detail"], body
