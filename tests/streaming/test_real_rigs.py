"""Real rigs over the service: a plain camera-list calibration (CMU Panoptic's layout) with its units,
an HD 8-camera recording, and sessions that render from frames shrunk to the viewer's size."""
import io
import json
import zipfile

import cv2
import numpy as np
import pytest

from harness.takes import jpeg, png
from tests.streaming.conftest import wait_recording
from tests.streaming.test_sockets import until
from workers.streaming.demo import demo_scene
from workers.streaming.params import Orbit, Viewpoint
from workers.streaming.recording import ArchiveWriter, RecordingArchive
from workers.streaming.session import RecordingSession, SessionLimits, shrunk_camera, shrunk_rig, source_factor
from workers.streaming.viewpoint import orbit_frame
from workers.sweep.rig import Rig
from workers.synth import default_arc_rig, render_views

HD = (1920, 1080)
DIST = [-0.25, 0.08, 0.0, 0.0, -0.01]


def panoptic(rig: Rig, scale: float = 100.0, types=None) -> bytes:
    """``rig`` as CMU Panoptic's calibration JSON, t in 1 / ``scale`` metres (cm by default)."""
    cams = [{"name": c.name, "type": types[i] if types else "hd", "resolution": [c.width, c.height], "panel": 0,
             "node": i, "K": c.K.tolist(), "distCoef": (c.dist if c.dist is not None else np.zeros(5)).tolist(),
             "R": c.R.tolist(), "t": (c.t * scale).reshape(3, 1).tolist()} for i, c in enumerate(rig.cameras)]
    return json.dumps({"calibDataSource": "test", "cameras": cams}).encode()


def hd_rig(n: int = 8) -> Rig:
    return Rig(tuple(default_arc_rig(n, arc_deg=90.0, width=HD[0], height=HD[1], fov_deg=60.0, dist=tuple(DIST))))


def test_a_panoptic_calibration_becomes_a_rig_in_metres(stream_client):
    rig = hd_rig()
    r = stream_client.post("/v1/rigs", files={"files": ("calibration_171026_pose3.json", panoptic(rig))})
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["format"] == "camera_list" and body["cameras"] == 8
    for got, want in zip(body["calibration"]["cameras"], rig.cameras):
        np.testing.assert_allclose(got["t"], want.t, atol=1e-9)  # centimetres in, metres stored
        np.testing.assert_allclose(got["dist"], DIST)
        assert (got["width"], got["height"]) == HD
    assert body["orbit"]["distance"] == pytest.approx(np.hypot(2.5, 0.8))
    in_mm = stream_client.post("/v1/rigs", files={"files": ("c.json", panoptic(rig, 1000.0))}, data={"units": "mm"})
    np.testing.assert_allclose(in_mm.json()["calibration"]["cameras"][3]["t"], rig[3].t, atol=1e-9)
    mixed = panoptic(rig, types=["hd", "vga"] * 4)
    only_hd = stream_client.post("/v1/rigs", files={"files": ("c.json", mixed)}, data={"camera_type": "hd"})
    assert only_hd.status_code == 201 and only_hd.json()["cameras"] == 4


def _bad_R(rig: Rig) -> bytes:
    d = json.loads(panoptic(rig))
    d["cameras"][2]["R"][0][0] += 0.01
    return json.dumps(d).encode()


@pytest.mark.parametrize("upload, data, status, error, problem", [
    ("bad_R", {}, 422, "invalid_rig", "camera 'cam02': field 'R': is not orthonormal"),
    ("ok", {"units": "furlongs"}, 422, "invalid_parameters", "units: 'furlongs' is not a unit (m, cm, mm)"),
    ("ok", {"units": "-2"}, 422, "invalid_parameters", "units: must be a positive number"),
    ("ok", {"camera_type": "vga"}, 422, "invalid_rig", "no camera of type 'vga' (the file has: hd)"),
])
def test_bad_camera_lists_and_units_are_422(stream_client, upload, data, status, error, problem):
    rig = hd_rig(3)
    content = _bad_R(rig) if upload == "bad_R" else panoptic(rig)
    r = stream_client.post("/v1/rigs", files={"files": ("calibration.json", content)}, data=data)
    assert r.status_code == status and r.json()["error"] == error, r.text
    assert problem in r.json()["detail"]


def test_an_hd_recording_of_8_cameras_imports_and_views_render_from_shrunk_frames(stream_client):
    """1920x1080 x 8 distorted cameras, 2 frames as a zip of JPEG folders: the import passes the
    default limits, and a 640x360 viewer is served from frames shrunk 3 times."""
    client = stream_client
    rig = hd_rig()
    small = shrunk_rig(rig, 4)  # render the studio at 480x270 (through the lens), then blow it up to HD
    sets = [render_views(demo_scene(f / 2), list(small.cameras), with_background=(f == 0)) for f in range(2)]
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as zf:
        for c, cam in enumerate(rig.cameras):
            for f in range(2):
                zf.writestr(f"take/{cam.name}/{f:04d}.jpg", jpeg(cv2.resize(sets[f][c].image, HD), 90))
            zf.writestr(f"take/backgrounds/{cam.name}.png", png(cv2.resize(sets[0][c].background, HD)))
    rig_id = client.post("/v1/rigs", files={"files": ("calibration.json", panoptic(rig))}).json()["id"]
    r = client.post(f"/v1/rigs/{rig_id}/recordings", files={"archive": ("take.zip", buf.getvalue())},
                    data={"params": '{"fps": 30}'})
    assert r.status_code == 202, r.text
    rec = wait_recording(client, rig_id, r.json()["id"], timeout=300)
    assert rec["state"] == "ready" and rec["frames"] == 2 and rec["background"] == "given", rec
    with client.websocket_connect(f"/v1/rigs/{rig_id}/view?source={rec['id']}") as ws:
        hello, _, _ = until(ws, "hello")
        assert [(c["width"], c["height"]) for c in hello["cameras"]] == [HD] * 8
        until(ws, "ready")
        for frame in (0, 1):
            ws.send_text(json.dumps({"id": frame + 1, "width": 640, "height": 360, "frame": frame, "planes": 32}))
            header, data, _ = until(ws, "frame", lambda h, i=frame + 1: h["id"] == i)
            assert header["source_factor"] == 3 and header["width"] == 640 and header["coverage"] > 0.2
            image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
            assert image.shape == (360, 640, 3) and image.std() > 20


# --- sessions at the viewer's size ----------------------------------------------------------------
def test_source_factor_and_shrunk_cameras():
    rig = hd_rig(2)
    assert source_factor(rig, 640, 360) == 3 and source_factor(rig, 640, 480) == 2
    assert source_factor(rig, 1920, 1080) == 1 and source_factor(rig, 4000, 3000) == 1
    assert source_factor(rig, 16, 16) == 8  # at most MAX_SOURCE_FACTOR
    cam = rig[0]
    small = shrunk_camera(cam, 3)
    assert (small.width, small.height) == (640, 360)
    np.testing.assert_allclose(small.dist, cam.dist)
    X = cam.backproject(np.array([[100.0, 50.0], [1800.0, 1000.0], [959.5, 539.5]]), 3.0)
    uv_big, _ = cam.project(X)
    uv_small, _ = small.project(X)
    np.testing.assert_allclose(uv_small, (uv_big + 0.5) / 3 - 0.5, atol=1e-9)  # the same pixel, 3 times smaller


@pytest.fixture(scope="module")
def big_take(tmp_path_factory):
    """4 cameras at 384x288 (the demo studio, 2 frames) in an archive."""
    rig = Rig(tuple(default_arc_rig(4, arc_deg=60.0, width=384, height=288)))
    sets = [render_views(demo_scene(f / 2), list(rig.cameras), with_background=(f == 0)) for f in range(2)]
    path = tmp_path_factory.mktemp("big") / "rec.zip"
    writer = ArchiveWriter(path, rig, 5.0)
    for views in sets:
        for c, v in enumerate(views):
            writer.add(c, v.image)
    for c, v in enumerate(sets[0]):
        writer.set_background(c, v.background)
    writer.finish("given")
    return rig, sets, path


def test_a_session_shrinks_each_frame_set_once_per_size_and_shows_what_a_camera_saw(big_take):
    rig, sets, path = big_take
    archive = RecordingArchive(path)
    reads = []
    frame_set = archive.frame_set
    archive.frame_set = lambda i: reads.append(i) or frame_set(i)
    session = RecordingSession(rig, archive, SessionLimits())
    assert session.source_factor == 1 and reads == [0]  # the protocol's default 320x240 view: no shrinking
    frame = orbit_frame(rig)

    def view(c, w, h, f, **kw):
        return Viewpoint(orbit=Orbit(azimuth=float(frame.azimuths[c]) + kw.pop("turn", 0.0)), width=w, height=h,
                         frame=f, planes=32, quality=95, **kw)

    for turn in (0.0, 2.0, 4.0):  # three viewpoints of frame 1 at 96x72: one read, one shrink
        header, _ = session.view("a", view(1, 96, 72, 1, turn=turn))
        assert header["source_factor"] == 4
    assert reads == [0, 1]
    header, data = session.view("b", view(2, 96, 72, 1))
    assert reads == [0, 1] and session.describe()["source_factors"] == [1, 4]
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR).astype(int)
    shrunk = cv2.resize(sets[1][2].image, (96, 72), interpolation=cv2.INTER_AREA)
    want = cv2.imdecode(np.frombuffer(jpeg(shrunk, 95), np.uint8), cv2.IMREAD_COLOR).astype(int)  # same encoder
    sil = cv2.resize(sets[1][2].silhouette.astype(np.uint8), (96, 72), interpolation=cv2.INTER_NEAREST)
    inside = cv2.erode(sil, np.ones((5, 5), np.uint8)).astype(bool)
    assert np.abs(image - want)[inside].mean() < 3  # the view from camera 2 is camera 2's shrunk frame
    session.view("c", view(1, 192, 144, 0))  # another size: its own factor, frame 0 read again
    assert session.source_factor == 2 and reads == [0, 1, 0]
    session.view("a", view(1, 96, 72, 1, turn=6.0))  # back to 96x72, frame 1: still held, no read
    assert reads == [0, 1, 0] and session.source_factor == 4
