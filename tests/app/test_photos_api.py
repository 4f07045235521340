"""The photo routes over HTTP: answers, the written tag, and every kind of bad input."""
from __future__ import annotations

import io
import struct
import zlib

import cv2
import numpy as np
import piexif
import pytest

from tests.app.photos import gradient_jpeg, noise_jpeg
from workers.common.datasets import dataset


def png_bytes(width=64, height=48) -> bytes:
    ok, buf = cv2.imencode(".png", np.full((height, width, 3), 128, np.uint8))
    assert ok
    return buf.tobytes()


def png_bomb(width=100_000, height=100_000) -> bytes:
    """A tiny PNG whose header announces ``width x height`` pixels."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b"")


@pytest.fixture
def client(client_factory):
    return client_factory(max_image_pixels=50_000_000)


@pytest.mark.parametrize("route", ["/v1/photos/orientation", "/v1/photos/orient"])
@pytest.mark.parametrize("data,status,code", [
    (b"", 400, "empty_file"),
    (b"this is plain text, not a photo" * 10, 415, "not_an_image"),
])
def test_unusable_files_are_4xx_with_a_reason(client, route, data, status, code):
    r = client.post(route, files={"file": ("x.jpg", data, "image/jpeg")})
    assert r.status_code == status, r.text
    body = r.json()
    assert body["error"] == code and body["detail"].startswith("x.jpg: ")


@pytest.mark.parametrize("route", ["/v1/photos/orientation", "/v1/photos/orient"])
def test_truncated_jpeg_is_422(client, route):
    data = noise_jpeg(1)
    r = client.post(route, files={"file": ("cut.jpg", data[: len(data) // 2], "image/jpeg")})
    assert r.status_code == 422 and r.json()["error"] == "truncated_image"


def test_decompression_bomb_is_refused_from_its_header(client):
    r = client.post("/v1/photos/orientation", files={"file": ("bomb.png", png_bomb(), "image/png")})
    assert r.status_code == 413
    assert r.json()["error"] == "too_many_pixels" and "50000000" in r.json()["detail"].replace(",", "")


def test_png_is_analysed_but_cannot_be_tagged(client):
    r = client.post("/v1/photos/orientation", files={"file": ("flat.png", png_bytes(), "image/png")})
    assert r.status_code == 200
    assert r.json()["decision"] == "rejected" and r.json()["orientation"] is None
    r = client.post("/v1/photos/orient", files={"file": ("flat.png", png_bytes(), "image/png")})
    assert r.status_code == 415 and r.json()["error"] == "unsupported_format"


def test_a_photo_without_a_face_is_rejected_and_returned_untouched(client):
    data = gradient_jpeg()
    r = client.post("/v1/photos/orientation", files={"file": ("n.jpg", data, "image/jpeg")})
    body = r.json()
    assert r.status_code == 200
    assert body["decision"] == "rejected" and body["orientation"] is None and body["faces"] == []
    assert body["cue"] == "none" and body["needs_review"] is True and body["reject_reason"] is not None
    assert body["elapsed_ms"] > 0
    r = client.post("/v1/photos/orient", files={"file": ("n.jpg", data, "image/jpeg")})
    assert r.status_code == 200 and r.content == data
    assert r.headers["x-orientation"] == "none"
    assert r.headers["x-orientation-decision"] == "rejected"
    assert r.headers["x-orientation-cue"] == "none" and r.headers["x-orientation-needs-review"] == "true"
    assert r.headers["x-orientation-action"] == "not_written_rejected"


def test_a_text_photo_without_faces_is_decided_by_its_text(client):
    from tests.orientation.test_orientation_text import needs_tesseract_reason, text_page, turned

    if needs_tesseract_reason():
        pytest.skip(needs_tesseract_reason())
    ok, buf = cv2.imencode(".jpg", turned(text_page(), 90), [cv2.IMWRITE_JPEG_QUALITY, 92])
    r = client.post("/v1/photos/orientation", files={"file": ("page.jpg", buf.tobytes(), "image/jpeg")})
    body = r.json()
    assert r.status_code == 200, r.text
    assert body["rotation_degrees"] == 90 and body["cue"] == "text" and body["needs_review"] is False
    assert body["text"]["status"] == "ran" and len(body["text"]["views"]) == 4
    ready = client.get("/readyz").json()["checks"]["orientation"]
    assert ready["ok"] and ready["text"]["available"] is True


def test_readiness_reports_a_missing_tesseract_and_faces_still_work(client_factory):
    client = client_factory(orientation_tesseract="/nonexistent/bin/tesseract")
    ready = client.get("/readyz")
    assert ready.status_code == 200  # optional: never a reason to be unready
    text = ready.json()["checks"]["orientation"]["text"]
    assert text["available"] is False and "faces only" in text["detail"]
    r = client.post("/v1/photos/orientation", files={"file": ("n.jpg", gradient_jpeg(), "image/jpeg")})
    assert r.status_code == 200 and r.json()["text"]["status"] == "unavailable" and r.json()["needs_review"]


def test_batch_limits(client_factory):
    client = client_factory(max_batch_files=2)
    files = [("files", (f"{i}.jpg", noise_jpeg(i, 64, 48), "image/jpeg")) for i in range(3)]
    r = client.post("/v1/photos/batches", files=files)
    assert r.status_code == 413 and r.json()["error"] == "too_many_files"
    assert client.get("/v1/jobs", params={"kind": "orientation.batch"}).json()["jobs"] == []  # nothing queued


def _real_face_photo():
    photo = dataset("faces", "dev", "face_recognition", "examples_obama-480p.jpg")
    if photo is None:
        pytest.skip("real face photos not available: set SWEEPCAST_DATA to the benchmark data")
    return photo


def test_real_rotated_face_gets_the_tag_that_shows_it_upright(client):
    upright = cv2.imread(str(_real_face_photo()), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
    stored = cv2.rotate(upright, cv2.ROTATE_90_CLOCKWISE)  # the camera was held sideways
    ok, buf = cv2.imencode(".jpg", stored, [cv2.IMWRITE_JPEG_QUALITY, 92])
    out = io.BytesIO()
    piexif.insert(piexif.dump({"0th": {piexif.ImageIFD.Make: b"TestCam"}}), buf.tobytes(), out)
    data = out.getvalue()
    r = client.post("/v1/photos/orient", files={"file": ("side.jpg", data, "image/jpeg")})
    assert r.status_code == 200, r.text
    if r.headers["x-orientation-decision"] == "rejected":
        pytest.skip("the detector rejected this photo (never guesses); see benchmarks for rates")
    assert r.headers["x-orientation"] == "8"
    exif = piexif.load(r.content)
    assert exif["0th"][piexif.ImageIFD.Orientation] == 8 and exif["0th"][piexif.ImageIFD.Make] == b"TestCam"
    shown = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)  # applies the tag
    assert shown.shape == upright.shape
    assert np.abs(shown.astype(int) - upright.astype(int)).mean() < 6
