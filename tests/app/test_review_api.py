"""The review queue of a photo batch over HTTP: what needs a person, and a person's decision written losslessly."""
from __future__ import annotations

import json

import cv2
import numpy as np
import piexif

from harness.photos import asymmetric_image
from tests.orientation.builders import encode, ifd0_entries, insert_app1, jpeg, rich_exif, split_around_app1


def review_photos() -> list[tuple[str, bytes, str]]:
    """Two photos nothing decides (no face, no text): a camera JPEG with EXIF but no Orientation, and a PNG."""
    camera = insert_app1(jpeg(asymmetric_image(600, 800), 92), rich_exif(orientation=None))
    return [("files", ("IMG_0001.jpg", camera, "image/jpeg")),
            ("files", ("scan.png", encode(asymmetric_image(300, 200), ".png"), "image/png"))]


def finished_batch(client, files) -> str:
    """Post a batch (faces only: the text cue off) and wait until it has finished; its id."""
    job = client.post("/v1/photos/batches", files=files, data={"text": "false"})
    assert job.status_code == 202, job.text
    with client.websocket_connect(f"/v1/jobs/{job.json()['id']}/events") as ws:
        while (event := ws.receive_json())["type"] != "final":
            pass
    assert event["job"]["state"] == "succeeded", event
    return job.json()["id"]


def test_a_persons_choice_is_written_losslessly_and_recorded_as_theirs(client_factory):
    client = client_factory()
    files = review_photos()
    original = files[0][1][1]
    job = finished_batch(client, files)

    queue = client.get(f"/v1/photos/batches/{job}/review").json()
    assert queue["photos"] == 2 and queue["reviewed"] == 0
    assert [(i["index"], i["reason"], i["review"]) for i in queue["items"]] == [(0, "no_cue", None), (1, "no_cue", None)]
    thumbs = [client.get(item["thumbnail"]) for item in queue["items"]]
    assert [t.status_code for t in thumbs] == [200, 200]
    assert {t.headers["content-type"] for t in thumbs} == {"image/jpeg"}
    small = [cv2.imdecode(np.frombuffer(t.content, np.uint8), cv2.IMREAD_COLOR) for t in thumbs]
    assert [s.shape for s in small] == [(240, 320, 3), (300, 200, 3)]  # 320 px long at most, never enlarged, colour
    expected = cv2.resize(asymmetric_image(600, 800), (320, 240), interpolation=cv2.INTER_AREA)
    assert np.abs(small[0].astype(int) - expected).mean() < 6  # the stored pixels, as stored (EXIF ignored)
    assert not [f for f in client.get(f"/v1/jobs/{job}").json()["result"]["files"] if f["name"].endswith(".jpg")]

    item = client.post(f"/v1/photos/batches/{job}/review/0", json={"rotation_degrees": 90, "reviewer": " Ada "})
    assert item.status_code == 200, item.text
    review = item.json()["review"]
    assert review["decided_by"] == "person" and review["reviewer"] == "Ada" and review["rotation_degrees"] == 90
    assert review["orientation"] == 6 and review["target"] == "exif-ifd0" and review["action"] == "written"

    fixed = client.get(f"/v1/jobs/{job}/results/{review['fixed_file']}")
    assert fixed.status_code == 200
    assert split_around_app1(fixed.content)[1] == split_around_app1(original)[1]  # the image data, byte for byte
    exif = piexif.load(fixed.content)
    assert exif["0th"][piexif.ImageIFD.Orientation] == 6 and exif["0th"][piexif.ImageIFD.Make] == b"SweepCam"
    assert set(ifd0_entries(original)) | {piexif.ImageIFD.Orientation} == set(ifd0_entries(fixed.content))

    left = client.post(f"/v1/photos/batches/{job}/review/1", json={"rotation_degrees": None, "reviewer": "Ada"}).json()
    assert left["review"]["action"] == "left_as_is" and left["review"]["fixed_file"] is None

    entries = client.get(f"/v1/jobs/{job}/results/report.json").json()
    assert [e["review"]["reviewer"] for e in entries] == ["Ada", "Ada"]
    assert entries[0]["fixed_file"] == review["fixed_file"] and entries[1]["fixed_file"] is None
    assert entries[0]["report"]["needs_review"]  # the engine's own report is kept beside the person's decision
    summary = client.get(f"/v1/jobs/{job}").json()["result"]["summary"]
    assert summary["needs_review"] == 2 and summary["reviewed"] == 2 and summary["written"] == 1
    assert client.get(f"/v1/photos/batches/{job}/review").json()["reviewed"] == 2

    # a second decision replaces the first
    again = client.post(f"/v1/photos/batches/{job}/review/0", json={"rotation_degrees": 180, "reviewer": "Bo"}).json()
    assert again["review"]["orientation"] == 3 and again["review"]["reviewer"] == "Bo"
    fixed = client.get(f"/v1/jobs/{job}/results/{again['review']['fixed_file']}").content
    assert piexif.load(fixed)["0th"][piexif.ImageIFD.Orientation] == 3


def test_review_errors_are_json_and_change_nothing(client_factory):
    client = client_factory()
    job = finished_batch(client, review_photos())
    before = client.get(f"/v1/jobs/{job}/results/report.json").content

    def error(method: str, path: str, status: int, code: str, **kwargs) -> None:
        r = client.request(method, path, **kwargs)
        assert r.status_code == status, r.text
        assert r.json()["error"] == code and r.json()["detail"], r.json()

    error("GET", "/v1/photos/batches/nope/review", 404, "job_not_found")
    error("POST", f"/v1/photos/batches/{job}/review/7", 404, "photo_not_found",
          json={"rotation_degrees": 90, "reviewer": "Ada"})
    error("GET", f"/v1/photos/batches/{job}/photos/2/thumbnail", 404, "photo_not_found")
    empty = finished_batch(client, [("files", ("empty.jpg", b"", "image/jpeg"))])
    error("GET", f"/v1/photos/batches/{empty}/photos/0/thumbnail", 400, "empty_file")
    error("GET", "/v1/photos/batches/nope/photos/0/thumbnail", 404, "job_not_found")
    for body in ({"rotation_degrees": 45, "reviewer": "Ada"}, {"rotation_degrees": 90, "reviewer": "   "},
                 {"rotation_degrees": 90}, {"rotation_degrees": 90, "reviewer": "Ada", "force": True}):
        r = client.post(f"/v1/photos/batches/{job}/review/0", json=body)
        assert r.status_code == 422 and r.json()["error"], (body, r.text)
    assert client.get(f"/v1/jobs/{job}/results/report.json").content == before
    assert json.loads(before)[0]["review"] is None


def test_the_review_page_is_served_with_its_assets(client_factory):
    client = client_factory()
    page = client.get("/review/any-job-id")
    assert page.status_code == 200 and "review.js" in page.text
    assert client.get("/review/assets/review.js").status_code == 200
