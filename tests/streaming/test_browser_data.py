"""What a viewer that renders in its browser gets from the server: frame sets over HTTP (immutable, cached,
lossless on request), a socket hello with the rig's geometry and no session, and the live stream's sets relayed
as the live client sent them."""
import json

import cv2
import numpy as np
import pytest
from starlette.websockets import WebSocketDisconnect

from app.routers import recordings
from harness.takes import frame_set, jpeg
from tests.streaming.conftest import add_recording, add_rig
from tests.streaming.test_sockets import receive, sessions_of, until
from workers.streaming.browser import atlas_columns, frame_atlas
from workers.sweep.weighting import METHOD_CODES


@pytest.fixture
def recorded(stream_client, take):
    rig_id = add_rig(stream_client, take)
    return stream_client, rig_id, add_recording(stream_client, rig_id, take)


def decode(data: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)


def test_frame_sets_come_as_immutable_cacheable_atlases(recorded, take, monkeypatch):
    client, rig_id, rec = recorded
    url = f"/v1/rigs/{rig_id}/recordings/{rec}/frames"
    r = client.get(f"{url}/1", params={"format": "png"})
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    assert "immutable" in r.headers["cache-control"] and r.headers["etag"]
    # lossless: exactly the recorded frames, tiled in rig order (2 columns for 4 cameras)
    assert atlas_columns(4) == 2
    assert np.array_equal(decode(r.content), frame_atlas(take.frames[1], take.rig, 1))
    assert np.array_equal(decode(client.get(f"{url}/background", params={"format": "png"}).content),
                          frame_atlas(take.backgrounds, take.rig, 1))
    again = client.get(f"{url}/1", params={"format": "png"}, headers={"If-None-Match": r.headers["etag"]})
    assert again.status_code == 304 and not again.content
    services = client.app.state.services
    encoded = services.atlases.encoded
    loads = []
    with monkeypatch.context() as patch:  # a load of the rig now would be recorded, and fail the request
        patch.setattr(recordings, "load_rig", lambda *args: loads.append(args))
        assert client.get(f"{url}/1", params={"format": "png"}).content == r.content
    assert services.atlases.encoded == encoded and not loads  # the second viewer's request cost no encode, no rig
    half = client.get(f"{url}/0", params={"factor": 2, "format": "jpeg", "quality": 95})
    assert half.headers["content-type"] == "image/jpeg" and half.headers["etag"] != r.headers["etag"]
    small = decode(half.content)
    assert small.shape == (2 * 36, 2 * 48, 3)  # 96x72 cameras shrunk by 2, two rows of two
    assert cv2.PSNR(small, frame_atlas(take.frames[0], take.rig, 2)) > 30


@pytest.mark.parametrize("path, params, status, code", [
    ("3", {}, 404, "frame_not_found"),
    ("-1", {}, 404, "frame_not_found"),
    ("backgrounds", {}, 404, "frame_not_found"),
    ("0", {"factor": 9}, 422, None),
    ("0", {"format": "gif"}, 422, None),
    ("0", {"quality": 10}, 422, None),
])
def test_bad_frame_set_requests_get_json_errors(recorded, path, params, status, code):
    client, rig_id, rec = recorded
    r = client.get(f"/v1/rigs/{rig_id}/recordings/{rec}/frames/{path}", params=params)
    assert r.status_code == status and r.headers["content-type"].startswith("application/json")
    if code:
        assert r.json()["error"] == code and "0..2" in r.json()["detail"]


def test_a_browser_viewer_of_a_recording_gets_the_geometry_and_starts_no_session(recorded, take):
    client, rig_id, rec = recorded
    with client.websocket_connect(f"/v1/rigs/{rig_id}/view?render=browser") as ws:
        hello, _, _ = until(ws, "hello")
        assert hello["render_mode"] == "browser" and hello["frames"] == 3 and hello["target_fps"] > 0
        spec = hello["render"]
        assert [c["name"] for c in hello["cameras"]] == take.rig.names and spec["radius"] > 0
        assert "cameras" not in spec and "orbit" not in spec  # said once, in the hello itself
        assert len(spec["poses"]) == len(take.rig) and spec["sources"][0]["factor"] == 1
        assert np.allclose(spec["sources"][0]["cameras"][0]["K"], take.rig.cameras[0].K)
        assert spec["rules"]["codes"]["method"] == METHOD_CODES and spec["rules"]["defaults"]["planes"] == 48
        assert spec["silhouettes"]["threshold"] == 20.0 and len(spec["silhouettes"]["clean"]) == 17  # the 5x5 disk
        assert len(spec["style"]["colour_map"]) == 256
        url = hello["frame_sets"]["url"].replace("{frame}", "2")
        assert client.get(url).status_code == 200
        until(ws, "ready")
        ws.send_text(json.dumps({"type": "ping"}))
        assert until(ws, "pong")
        ws.send_text(json.dumps({"id": 1, "width": 96, "height": 72}))
        error, _, _ = until(ws, "error")
        assert error["error"] == "client_renders" and "render=browser" in error["detail"]
        assert sessions_of(rig_id) == []  # nothing renders on the server for this viewer
        ws.send_bytes(b"\x00")
        with pytest.raises(WebSocketDisconnect) as closed:
            receive(ws)
        assert closed.value.code == 1003


def test_live_sets_reach_browser_viewers_as_sent_and_the_background_model_is_served(stream_client, take):
    client = stream_client
    rig_id = add_rig(client, take)
    with client.websocket_connect(f"/v1/rigs/{rig_id}/live") as live:
        until(live, "hello")
        live.send_bytes(frame_set([jpeg(i) for i in take.frames[0]], seq=1))
        until(live, "ack")
        assert client.get(f"/v1/rigs/{rig_id}/live/background").json()["error"] == "no_background"
        with client.websocket_connect(f"/v1/rigs/{rig_id}/view?source=live&render=browser") as viewer:
            hello, _, _ = until(viewer, "hello")
            assert hello["live"]["background_url"].endswith(f"/{rig_id}/live/background")
            backgrounds = [jpeg(b) for b in take.backgrounds]
            live.send_bytes(frame_set(backgrounds, background=True, seq=2))
            until(live, "ack")
            header, payload, _ = until(viewer, "frame", lambda h: h.get("seq") == 2)
            assert header["type"] == "frame_set" and header["background"] is True
            parts, offset = [], 0
            for size in header["sizes"]:
                parts.append(bytes(payload[offset:offset + size]))
                offset += size
            assert parts == backgrounds  # relayed exactly as the live client sent them
            model = client.get(f"/v1/rigs/{rig_id}/live/background")
            assert model.status_code == 200 and model.headers["content-type"] == "image/png"
            assert decode(model.content).shape == (2 * 72, 2 * 96, 3)
            live.send_bytes(frame_set([jpeg(i) for i in take.frames[1]], seq=3))
            header, _, _ = until(viewer, "frame", lambda h: h.get("seq") == 3)
            assert header["background"] is False and not header["resync"]


def test_a_browser_viewer_on_another_replica_gets_live_sets_from_the_session(client_factory, take):
    """The live client on one API process, the browser viewer on another: the viewer's process polls the
    rig's live session for the sets."""
    a = client_factory(session_idle_seconds=5.0)
    b = client_factory(session_idle_seconds=5.0)  # the same data folder (settings_factory): a second replica
    rig_id = add_rig(a, take)
    with a.websocket_connect(f"/v1/rigs/{rig_id}/live") as live, \
            b.websocket_connect(f"/v1/rigs/{rig_id}/view?source=live&render=browser") as viewer:
        until(live, "hello")
        until(viewer, "ready")
        live.send_bytes(frame_set([jpeg(i) for i in take.frames[2]], seq=7))
        live_seq = until(live, "ack")[0]["live_seq"]
        header, _, _ = until(viewer, "frame", lambda h: h.get("seq") == live_seq)
        assert header["type"] == "frame_set" and len(header["sizes"]) == 4
