"""Rigs, recordings and batch renders over HTTP (the service on a local Ray)."""
import io
import zipfile

import numpy as np
import pytest

from harness.takes import png, rig_json, write_videos, zip_bytes
from tests.streaming.conftest import add_recording, add_rig, wait_recording, wait_until
from workers.camera import rotation_to_quat
from workers.streaming.demo import DEMO_SIZE
from workers.streaming.video import probe_video


def colmap_text(rig) -> tuple[str, str]:
    cams, images = [], []
    for i, c in enumerate(rig.cameras, 1):
        K = c.K
        cams.append(f"{i} PINHOLE {c.width} {c.height} {K[0, 0]} {K[1, 1]} {K[0, 2] + 0.5} {K[1, 2] + 0.5}")
        q = rotation_to_quat(c.R)
        images.append(f"{i} {' '.join(map(str, q))} {' '.join(map(str, c.t))} {i} {c.name}.png\n")
    return "\n".join(cams) + "\n", "\n".join(images)


def opencv_yaml(rig) -> str:
    def mat(rows, cols, values):
        return f"!!opencv-matrix\n      rows: {rows}\n      cols: {cols}\n      dt: d\n      data: [{', '.join(map(str, values))}]"
    body = "".join(f"  - name: {c.name}\n    K: {mat(3, 3, c.K.ravel())}\n    R: {mat(3, 3, c.R.ravel())}\n"
                   f"    t: {mat(3, 1, c.t)}\n    width: {c.width}\n    height: {c.height}\n" for c in rig.cameras)
    return "%YAML:1.0\n---\ncameras:\n" + body


def test_rig_crud_in_every_calibration_format(stream_client, take):
    client = stream_client
    rig = take.rig
    cameras_txt, images_txt = colmap_text(rig)
    par = f"{len(rig)}\n" + "".join(
        f"{c.name}.png {' '.join(map(str, c.K.ravel()))} {' '.join(map(str, c.R.ravel()))} {' '.join(map(str, c.t))}\n"
        for c in rig.cameras)
    uploads = {
        "json": ([("files", ("rig.json", rig_json(rig)))], {}),
        "opencv": ([("files", ("rig.yml", opencv_yaml(rig).encode()))], {}),
        "colmap": ([("files", ("cameras.txt", cameras_txt.encode())), ("files", ("images.txt", images_txt.encode()))], {}),
        "middlebury": ([("files", ("take_par.txt", par.encode()))], {"width": "96", "height": "72"}),
    }
    ids = {}
    for fmt, (files, data) in uploads.items():
        r = client.post("/v1/rigs", files=files, data=data)
        assert r.status_code == 201, (fmt, r.text)
        body = r.json()
        assert body["format"] == fmt and body["cameras"] == 4 and r.headers["location"] == f"/v1/rigs/{body['id']}"
        for got, want in zip(body["calibration"]["cameras"], rig.cameras):
            np.testing.assert_allclose(np.array(got["R"]) @ want.R.T, np.eye(3), atol=1e-6)
            np.testing.assert_allclose(got["t"], want.t, atol=1e-6)
            np.testing.assert_allclose(got["K"], want.K, atol=1e-6)
        np.testing.assert_allclose(body["orbit"]["camera_azimuths"], [-45, -15, 15, 45], atol=1e-6)
        ids[fmt] = body["id"]
    listed = client.get("/v1/rigs").json()["rigs"]
    assert {r["id"] for r in listed} == set(ids.values())
    assert client.delete(f"/v1/rigs/{ids['json']}").status_code == 204
    assert client.get(f"/v1/rigs/{ids['json']}").status_code == 404
    assert client.get("/v1/rigs/..%2F..%2Fetc").status_code == 404


@pytest.mark.parametrize("files, data, problem", [
    ([("files", ("rig.json", b'{"cameras": [{"name": "a"}]}'))], {}, "field 'K': missing"),
    ([("files", ("rig.json", b"not json"))], {}, "not valid JSON"),
    ([("files", ("rig.yml", b"garbage: [1, 2\n"))], {}, "rig.yml is not a valid OpenCV FileStorage file"),
    ([("files", ("take_par.txt", b"1\n"))], {}, "give the form fields width and height"),
    ([("files", ("images.txt", b""))], {}, "needs both cameras.txt and images.txt"),
    ([("files", ("a.json", b"{}")), ("files", ("b.json", b"{}"))], {}, "only understood as COLMAP"),
])
def test_unusable_calibrations_are_422(stream_client, files, data, problem):
    r = stream_client.post("/v1/rigs", files=files, data=data)
    assert r.status_code == 422 and r.json()["error"] == "invalid_rig"
    assert problem in r.json()["detail"]


def test_rig_limits(client_factory, take):
    client = client_factory(max_rig_cameras=3)
    r = client.post("/v1/rigs", files={"files": ("rig.json", rig_json(take.rig))})
    assert r.status_code == 422 and "4 cameras; the limit is 3" in r.json()["detail"]


def test_recording_from_videos_then_from_folders(stream_client, take, tmp_path):
    client = stream_client
    rig_id = add_rig(client, take)
    paths = write_videos(take, tmp_path)
    files = [("videos", (p.name, p.read_bytes(), "video/mp4")) for p in reversed(paths)]  # matched by name
    files += [("backgrounds", (f"{n}.png", png(b), "image/png")) for n, b in zip(take.rig.names, take.backgrounds)]
    r = client.post(f"/v1/rigs/{rig_id}/recordings", files=files, data={"params": '{"name": "take 1"}'})
    assert r.status_code == 202, r.text
    assert r.json()["state"] == "processing" and r.headers["location"].endswith(r.json()["id"])
    rec = wait_recording(client, rig_id, r.json()["id"])
    assert rec["state"] == "ready", rec
    assert (rec["name"], rec["frames"], rec["fps"], rec["background"]) == ("take 1", 3, 10.0, "given")
    job = client.get(f"/v1/jobs/{rec['job_id']}").json()
    assert job["kind"] == "streaming.recording" and job["progress"]["fraction"] == 1.0
    second = add_recording(client, rig_id, take)
    listed = client.get(f"/v1/rigs/{rig_id}/recordings").json()["recordings"]
    assert [x["id"] for x in listed] == [rec["id"], second]
    refused = client.delete(f"/v1/jobs/{rec['job_id']}")  # the job's results are the recording
    assert refused.status_code == 409 and f"/v1/rigs/{rig_id}/recordings/" in refused.json()["detail"]
    assert client.get(f"/v1/rigs/{rig_id}/recordings/{rec['id']}").json()["state"] == "ready"
    assert client.delete(f"/v1/rigs/{rig_id}/recordings/{rec['id']}").status_code == 204
    assert client.get(f"/v1/rigs/{rig_id}/recordings/{rec['id']}").status_code == 404
    assert client.get(f"/v1/jobs/{rec['job_id']}").status_code == 404


def test_bad_recordings_are_refused_at_once(stream_client, take, tmp_path):
    client = stream_client
    rig_id = add_rig(client, take)
    uneven = write_videos(take, tmp_path, frames=[3, 3, 2, 3])
    r = client.post(f"/v1/rigs/{rig_id}/recordings", files=[("videos", (p.name, p.read_bytes())) for p in uneven])
    assert r.status_code == 422 and r.json()["error"] == "invalid_recording"
    assert "differ in length (cam00.mp4: 3, cam01.mp4: 3, cam02.mp4: 2, cam03.mp4: 3 frames)" in r.json()["detail"]
    r = client.post(f"/v1/rigs/{rig_id}/recordings", files=[("videos", (p.name, p.read_bytes())) for p in uneven[:2]])
    assert r.status_code == 422 and "missing: cam02, cam03" in r.json()["detail"]
    r = client.post(f"/v1/rigs/{rig_id}/recordings", files=[("videos", (f"cam0{i}.mp4", b"not a video")) for i in range(4)])
    assert r.status_code == 422 and "cam00.mp4 is not a readable video" in r.json()["detail"]
    r = client.post(f"/v1/rigs/{rig_id}/recordings", files={"archive": ("t.zip", zip_bytes(take, frames=[3, 1, 3, 3]))})
    assert r.status_code == 422 and "cam01: 1" in r.json()["detail"]
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name in take.rig.names:
            zf.writestr(f"{name}/0.png", png(np.zeros((36, 48, 3), np.uint8)))
    r = client.post(f"/v1/rigs/{rig_id}/recordings", files={"archive": ("t.zip", buf.getvalue())})
    assert r.status_code == 422 and "is 48x36; camera cam00 is calibrated at 96x72" in r.json()["detail"]
    r = client.post(f"/v1/rigs/{rig_id}/recordings")
    assert r.status_code == 422 and "either 'videos'" in r.json()["detail"]
    assert client.post("/v1/rigs/nope/recordings", files={"archive": ("t.zip", b"x")}).status_code == 404
    assert client.get(f"/v1/rigs/{rig_id}/recordings").json()["recordings"] == []


def test_batch_render_job_with_progress_per_frame(stream_client, take):
    client = stream_client
    rig_id = add_rig(client, take)
    rec = add_recording(client, rig_id, take)
    body = {"recording_id": rec, "keyframes": [{"orbit": {"azimuth": -30}}, {"orbit": {"azimuth": 0}},
                                               {"orbit": {"azimuth": 30, "distance": 2.2}}],
            "frames": 4, "width": 64, "height": 48, "planes": 24}
    r = client.post(f"/v1/rigs/{rig_id}/renders", json=body)
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    with client.websocket_connect(f"/v1/jobs/{job_id}/events") as ws:
        events = []
        while (event := ws.receive_json())["type"] != "final":
            events.append(event)
    assert event["job"]["state"] == "succeeded", event["job"]
    stages = {e["stage"] for e in events if e["type"] == "progress" and e["stage"].startswith("frame")}
    assert stages <= {f"frame {k}/4" for k in range(1, 5)}
    if events and events[0]["type"] == "snapshot":  # followed live: the last frame was reported
        assert "frame 4/4" in stages
    video = client.get(f"/v1/jobs/{job_id}/results/video.mp4")
    assert video.status_code == 200 and video.headers["content-type"] == "video/mp4"
    info = probe_video(io.BytesIO(video.content))
    assert (info.frames, info.width, info.height) == (4, 64, 48)
    with zipfile.ZipFile(io.BytesIO(client.get(f"/v1/jobs/{job_id}/results/depth.zip").content)) as zf:
        assert sorted(n for n in zf.namelist() if n.startswith("depth/")) == [f"depth/{k:06d}.png" for k in range(4)]


@pytest.mark.parametrize("body, problem", [
    ({"orbit": {}, "frame_start": 5}, "out of range: recording"),
    ({"orbit": {}, "width": 4000, "height": 4000}, "over the limit"),
    ({"orbit": {}, "planes": 1000}, "over the limit of 256"),
    ({}, "exactly one camera path"),
])
def test_bad_render_requests_are_422(stream_client, take, body, problem):
    client = stream_client
    rig_id = add_rig(client, take)
    rec = add_recording(client, rig_id, take)
    r = client.post(f"/v1/rigs/{rig_id}/renders", json={"recording_id": rec, **body})
    assert r.status_code == 422 and problem in r.text


def test_render_of_an_unknown_recording_is_404(stream_client, take):
    rig_id = add_rig(stream_client, take)
    r = stream_client.post(f"/v1/rigs/{rig_id}/renders", json={"recording_id": "nope", "orbit": {}})
    assert r.status_code == 404 and r.json()["error"] == "recording_not_found"


def test_first_start_creates_the_demo_rig_and_starts_its_recording(client_factory):
    client = client_factory(demo_rig=True)
    assert wait_until(lambda: client.get("/v1/rigs").json()["rigs"], timeout=30)
    rig = client.get("/v1/rigs").json()["rigs"][0]
    assert rig["demo"] and rig["cameras"] == 10
    detail = client.get(f"/v1/rigs/{rig['id']}").json()
    assert (detail["calibration"]["cameras"][0]["width"], detail["calibration"]["cameras"][0]["height"]) == DEMO_SIZE
    (rec,) = detail["recordings"]
    assert rec["kind"] == "demo" and rec["state"] in ("processing", "ready")
    job = client.get(f"/v1/jobs/{rec['job_id']}").json()
    assert job["kind"] == "streaming.demo" and job["params"] == {"frames": 12, "fps": 6.0}
    client.delete(f"/v1/jobs/{rec['job_id']}")  # the demo job itself is tested small in test_jobs.py
    assert client.get(f"/v1/rigs/{rig['id']}/recordings/{rec['id']}").json()["state"] == "failed"

    again = client_factory(demo_rig=True)  # the next start (same data folder) renders it again
    assert wait_until(lambda: len(again.get(f"/v1/rigs/{rig['id']}/recordings").json()["recordings"]) == 2)
    assert [r["id"] for r in again.get("/v1/rigs").json()["rigs"]] == [rig["id"]]
    retry = again.get(f"/v1/rigs/{rig['id']}/recordings").json()["recordings"][1]
    assert retry["state"] in ("processing", "ready")
    again.delete(f"/v1/jobs/{retry['job_id']}")


def test_deeply_nested_json_in_a_form_field_or_a_body_is_a_4xx_not_a_500(stream_client, take):
    client = stream_client
    rig_id = add_rig(client, take)
    deep = "[" * 100000 + "]" * 100000
    r = client.post(f"/v1/rigs/{rig_id}/recordings", files={"archive": ("take.zip", zip_bytes(take))},
                    data={"params": deep})
    assert r.status_code == 422 and r.json()["error"] == "invalid_parameters", r.text
    assert "recursion limit" in r.json()["detail"]
    r = client.post(f"/v1/rigs/{rig_id}/renders", content=deep, headers={"content-type": "application/json"})
    assert 400 <= r.status_code < 500 and set(r.json()) >= {"error", "detail"}, r.text
    r = client.post("/v1/rigs", files={"files": ("rig.json", deep.encode())})
    assert r.status_code == 422 and "nests too deeply" in r.json()["detail"], r.text
