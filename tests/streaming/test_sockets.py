"""Viewer and live-ingest sockets end to end: frames, latest-wins, bad input, sharing, idle end, restarts."""
import json
import os
import signal
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
import ray
from starlette.websockets import WebSocketDisconnect

from harness.servers import alive
from harness.takes import frame_set, jpeg
from app.routers.rig_sockets import MAX_TEXT_CHARS
from app.stored_rigs import session_config
from tests.streaming.conftest import IDLE_S, add_recording, add_rig, wait_until
from workers.streaming import actor
from workers.streaming.framing import unpack_message

VIEW = {"width": 96, "height": 72, "planes": 24}


def receive(ws) -> tuple[str, dict, bytes | None]:
    """("json", message, None) or ("frame", header, jpeg)."""
    message = ws.receive()
    if message["type"] == "websocket.close":
        raise WebSocketDisconnect(message.get("code", 1000), message.get("reason"))
    if message.get("bytes") is not None:
        header, payload = unpack_message(message["bytes"])
        return "frame", header, bytes(payload)
    return "json", json.loads(message["text"]), None


def until(ws, kind: str, predicate=lambda m: True, limit: int = 200) -> tuple[dict, bytes | None, list[dict]]:
    """Read until a message of ``kind`` ("frame" or a JSON type) satisfies ``predicate``; return it,
    its payload and the JSON messages seen on the way."""
    seen = []
    for _ in range(limit):
        got, message, payload = receive(ws)
        if (got == "frame" and kind == "frame" or got == "json" and message.get("type") == kind) and predicate(message):
            return message, payload, seen
        seen.append(message)
    raise AssertionError(f"no {kind} message in {limit}: {seen[-5:]}")


def sessions_of(rig_id: str) -> list[dict]:
    return [s for s in actor.list_sessions() if s["rig_id"] == rig_id]


@pytest.fixture
def recorded(stream_client, take):
    rig_id = add_rig(stream_client, take)
    return stream_client, rig_id, add_recording(stream_client, rig_id, take)


def test_viewer_gets_frames_and_only_the_latest_viewpoint_is_rendered(recorded):
    client, rig_id, rec = recorded
    with client.websocket_connect(f"/v1/rigs/{rig_id}/view") as ws:  # default source: the newest ready recording
        hello, _, _ = until(ws, "hello")
        assert hello["source"] == rec and hello["frames"] == 3 and len(hello["cameras"]) == 4
        until(ws, "ready")
        for i in range(1, 31):  # sent faster than a 320x240 view renders anywhere
            ws.send_text(json.dumps({"id": i, "orbit": {"azimuth": i - 15.0}, "frame": i % 3, "width": 320,
                                     "height": 240, "planes": 48}))
        ids = []
        while not ids or ids[-1] != 30:
            header, data, seen = until(ws, "frame")
            assert not seen
            ids.append(header["id"])
    assert ids == sorted(ids) and len(ids) < 30  # stale viewpoints were never rendered
    assert header["frame"] == 0 and header["skipped"] >= 30 - len(ids)
    near, far = header["depth_range"]
    assert 0 < near < far and header["render_ms"] > 0 and header["encode_ms"] >= 0
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == (240, 320, 3) and image.max() > 0


def test_bad_input_gets_an_error_and_other_viewers_keep_their_session(recorded):
    client, rig_id, rec = recorded
    with client.websocket_connect(f"/v1/rigs/{rig_id}/view?source={rec}") as a, \
            client.websocket_connect(f"/v1/rigs/{rig_id}/view?source={rec}") as b:
        until(a, "ready")
        until(b, "ready")
        assert len(sessions_of(rig_id)) == 1  # one actor per (rig, source), shared
        bad = [
            ('{"id": 1, "fov": NaN}', "bad_viewpoint", "finite"),
            ('{"id": 2, "fov": 179}', "bad_viewpoint", "fov"),
            ('{"id": 3, "width": 4000, "height": 4000}', "too_large", "over the limit"),
            ('{"id": 4, "frame": 99, "width": 96, "height": 72}', "bad_frame", "frame 99 is out of range"),
            ('{"id": 5, "look_at": {"eye": [0, 3, 0.5], "target": [0, 6, 0.5]}}', "bad_view", "behind"),
            ("{not json", "bad_json", "not JSON"),
        ]
        for text, code, detail in bad:
            a.send_text(text)
            error, _, _ = until(a, "error")
            assert error["error"] == code and detail in error["detail"], error
        a.send_text(json.dumps({**VIEW, "id": 6}))
        assert until(a, "frame")[0]["id"] == 6  # the socket still works
        a.send_bytes(b"\x00\x01")
        with pytest.raises(WebSocketDisconnect) as closed:
            until(a, "frame")
        assert closed.value.code == 1003
        b.send_text(json.dumps({**VIEW, "id": 7, "overlay": "regions"}))
        header, _, _ = until(b, "frame")
        assert header["id"] == 7 and header["overlay"] == "regions"
        def listed() -> dict:
            (entry,) = [x for x in client.get("/v1/sessions").json()["sessions"] if x["rig_id"] == rig_id]
            return entry

        assert wait_until(lambda: listed()["info"]["viewers"] == 1)  # a left when it was closed
        assert listed()["source"] == rec and listed()["info"]["restarted"] is False
        assert listed()["info"]["node_id"] == ray.get_runtime_context().get_node_id()  # the one local node
        assert listed()["info"]["renders"] >= 2


@pytest.mark.parametrize("path, code", [
    ("/v1/rigs/nope/view", "rig_not_found"),
    ("/v1/rigs/{rig}/view?source=nope", "recording_not_found"),
    ("/v1/rigs/nope/live", "rig_not_found"),
])
def test_unknown_rig_or_recording_closes_with_1008(stream_client, take, path, code):
    rig_id = add_rig(stream_client, take)
    with stream_client.websocket_connect(path.format(rig=rig_id)) as ws:
        error, _, _ = until(ws, "error")
        assert error["error"] == code
        with pytest.raises(WebSocketDisconnect) as closed:
            receive(ws)
    assert closed.value.code == 1008


def test_sockets_need_the_key_when_the_service_has_keys(client_factory, take):
    client = client_factory(api_keys=["k"])
    r = client.post("/v1/rigs", files={"files": ("rig.json", b"{}")})
    assert r.status_code == 401
    with pytest.raises(WebSocketDisconnect) as closed:
        with client.websocket_connect("/v1/rigs/x/view") as ws:
            ws.receive()
    assert closed.value.code == 1008
    with client.websocket_connect("/v1/rigs/x/view?access_token=k") as ws:
        assert until(ws, "error")[0]["error"] == "rig_not_found"


def test_a_viewer_that_leaves_mid_render_leaks_nothing(recorded):
    client, rig_id, rec = recorded
    with client.websocket_connect(f"/v1/rigs/{rig_id}/view?source={rec}") as ws:
        until(ws, "ready")
        ws.send_text(json.dumps({**VIEW, "id": 1, "width": 320, "height": 240, "planes": 96}))
    assert len(sessions_of(rig_id)) == 1
    assert wait_until(lambda: not sessions_of(rig_id), timeout=IDLE_S + 20)  # the actor ends after the idle timeout


def test_live_ingest_feeds_live_viewers_and_survives_bad_frame_sets(stream_client, take):
    client = stream_client
    rig_id = add_rig(client, take)
    with client.websocket_connect(f"/v1/rigs/{rig_id}/live") as live:
        hello, _, _ = until(live, "hello")
        assert [c["name"] for c in hello["cameras"]] == take.rig.names
        live.send_bytes(frame_set([jpeg(b) for b in take.backgrounds], background=True, seq=1))
        ack, _, _ = until(live, "ack")
        assert ack["seq"] == 1 and ack["live_seq"] == 1 and ack["background_model"] is True
        names = list(reversed(take.rig.names))
        live.send_bytes(frame_set([jpeg(i) for i in reversed(take.frames[0])], cameras=names, seq=2))
        assert until(live, "ack")[0]["live_seq"] == 2
        with client.websocket_connect(f"/v1/rigs/{rig_id}/view?source=live") as viewer:
            until(viewer, "ready")
            viewer.send_text(json.dumps({**VIEW, "id": 1, "frame": "live"}))
            header, _, _ = until(viewer, "frame")
            assert header["frame"] == "live" and header["seq"] == 2 and header["coverage"] > 0.05
            live.send_bytes(frame_set([jpeg(i) for i in take.frames[1][:3]], seq=3))
            error, _, _ = until(live, "error")
            assert error["error"] == "bad_frame_set" and "3 images; the rig has 4 cameras" in error["detail"]
            broken = [jpeg(i) for i in take.frames[1]]
            broken[1] = b"\xff\xd8" + b"\x00" * 50
            live.send_bytes(frame_set(broken, seq=4))
            error, _, _ = until(live, "error")
            assert error["error"] == "bad_image" and "cam01" in error["detail"] and error["seq"] == 4
            live.send_bytes(frame_set([jpeg(i) for i in take.frames[2]], seq=5))
            assert until(live, "ack")[0]["live_seq"] == 3  # the bad sets changed nothing
            viewer.send_text(json.dumps({**VIEW, "id": 2, "frame": "live"}))
            assert until(viewer, "frame")[0]["seq"] == 3
            live.send_text("hello")
            with pytest.raises(WebSocketDisconnect) as closed:
                until(live, "ack")
            assert closed.value.code == 1003
            viewer.send_text(json.dumps({**VIEW, "id": 3, "frame": "live"}))
            assert until(viewer, "frame")[0]["id"] == 3  # the viewer's session goes on


@pytest.mark.parametrize("source", ["recording", "live"])
def test_a_crashed_session_restarts_and_reloads_from_the_blob_store(stream_client, take, source):
    client = stream_client
    rig_id = add_rig(client, take)
    if source == "live":
        with client.websocket_connect(f"/v1/rigs/{rig_id}/live") as live:
            live.send_bytes(frame_set([jpeg(b) for b in take.backgrounds], background=True))
            until(live, "ack")
            live.send_bytes(frame_set([jpeg(i) for i in take.frames[1]]))
            until(live, "ack")
        frame = "live"
    else:
        source = add_recording(client, rig_id, take)
        frame = 2
    with client.websocket_connect(f"/v1/rigs/{rig_id}/view?source={source}") as ws:
        until(ws, "ready")
        ws.send_text(json.dumps({**VIEW, "id": 1, "frame": frame}))
        before, _, _ = until(ws, "frame")
        (session,) = sessions_of(rig_id)
        if source == "live":  # the latest set is stored within the persistence interval
            assert wait_until(lambda: actor.session_info(session["name"])["persisted_seq"] == 2)
        pid = actor.session_info(session["name"])["pid"]
        ray.kill(ray.get_actor(session["name"], namespace=actor.NAMESPACE), no_restart=False)
        # ray.kill only asks: a request sent before the process is gone is answered by it, as if nothing happened
        assert wait_until(lambda: not alive(pid), timeout=30)
        ws.send_text(json.dumps({**VIEW, "id": 2, "frame": frame}))
        got, message, _ = receive(ws)
        if got == "json":  # it went to the dead process: reported once, never resent (it might be the cause)
            assert message["error"] == "session_restarting" and message["id"] == 2, message
            ws.send_text(json.dumps({**VIEW, "id": 3, "frame": frame}))
            message, _, seen = until(ws, "frame", limit=50)
            assert not seen
        after = message
    info = actor.session_info(session["name"])
    assert info["restarted"] is True and info["pid"] != pid
    assert after["id"] in (2, 3) and after["seq"] == before["seq"]
    assert after["coverage"] == pytest.approx(before["coverage"], abs=0.02)
    assert after["depth_found"] == pytest.approx(before["depth_found"], abs=0.05)


# --- failures inside the session ------------------------------------------------------------------
RAISES_WIDTH, CRASHES_WIDTH = 97, 98


def crash_log(rig_id: str) -> Path:
    return Path(tempfile.gettempdir()) / f"sweepcast-test-crashes-{rig_id}"


class FaultyHost(actor.SessionHost):
    """A session actor whose renderer raises for views RAISES_WIDTH wide and kills its own process
    (as a segfault would) for views CRASHES_WIDTH wide, noting each crash in crash_log()."""

    def _load(self):
        session = super()._load()
        render = session.renderer.render
        log = crash_log(self.config.rig_id)

        def faulty(cam, options=None, **kwargs):
            if cam.width == RAISES_WIDTH:
                raise FloatingPointError("injected: the sweep went wrong")
            if cam.width == CRASHES_WIDTH:
                with log.open("a") as f:
                    f.write(f"{os.getpid()}\n")
                os.kill(os.getpid(), signal.SIGKILL)
            return render(cam, options, **kwargs)

        session.renderer.render = faulty
        return session


FaultyActor = ray.remote(FaultyHost)


@pytest.fixture
def faulty(recorded):
    """A recording whose session actor (made before any viewer) is a FaultyHost."""
    client, rig_id, rec = recorded
    svc = client.app.state.services
    handle = actor.get_or_create(session_config(svc, rig_id, rec), svc.settings.session_resources, FaultyActor)
    pid = ray.get(handle.info.remote())["pid"]
    yield client, rig_id, rec, pid
    actor.end_sessions(rig_id)
    crash_log(rig_id).unlink(missing_ok=True)


def test_a_renderer_exception_costs_one_viewpoint_not_the_session(faulty):
    client, rig_id, rec, pid = faulty
    with client.websocket_connect(f"/v1/rigs/{rig_id}/view?source={rec}") as ws:
        ready, _, _ = until(ws, "ready")
        assert ready["session"]["pid"] == pid  # the viewer found the faulty actor
        ws.send_text(json.dumps({**VIEW, "id": 1, "frame": 1}))
        assert until(ws, "frame")[0]["id"] == 1
        ws.send_text(json.dumps({**VIEW, "id": 2, "frame": 2, "width": RAISES_WIDTH}))
        error, _, seen = until(ws, "error")
        assert not seen and error["error"] == "render_failed" and error["id"] == 2
        assert "FloatingPointError: injected" in error["detail"]
        ws.send_text(json.dumps({**VIEW, "id": 3, "frame": 1}))
        header, data, seen = until(ws, "frame")
        assert not seen and header["id"] == 3 and header["frame"] == 1 and header["reshaded"] is False
        assert cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR).shape == (72, 96, 3)
    (session,) = sessions_of(rig_id)
    info = actor.session_info(session["name"])
    assert info["pid"] == pid and info["restarted"] is False and info["failures"] == 1


def test_a_crash_during_a_render_is_reported_once_and_never_resent(faulty):
    client, rig_id, rec, pid = faulty
    with client.websocket_connect(f"/v1/rigs/{rig_id}/view?source={rec}") as ws:
        until(ws, "ready")
        ws.send_text(json.dumps({**VIEW, "id": 1, "width": CRASHES_WIDTH}))
        error, _, seen = until(ws, "error")
        assert not seen and error["error"] == "session_restarting" and error["id"] == 1
        ws.send_text(json.dumps({**VIEW, "id": 2, "frame": 2}))
        header, _, seen = until(ws, "frame")
        assert not seen and header["id"] == 2 and header["frame"] == 2
    (session,) = sessions_of(rig_id)
    info = actor.session_info(session["name"])
    assert info["restarted"] is True and info["pid"] != pid
    # The viewpoint that crashed the renderer was not sent again: one crash, one restart.
    assert len(crash_log(rig_id).read_text().split()) == 1


# --- hostile text messages ------------------------------------------------------------------------
DEEP = "[" * 100000 + "]" * 100000


def test_deep_or_huge_text_gets_an_error_and_the_viewer_socket_stays_open(recorded):
    client, rig_id, rec = recorded
    with client.websocket_connect(f"/v1/rigs/{rig_id}/view?source={rec}") as ws:
        until(ws, "ready")
        ws.send_text(DEEP)
        error, _, _ = until(ws, "error")
        assert error["error"] == "message_too_large" and str(MAX_TEXT_CHARS) in error["detail"]
        ws.send_text("[" * (MAX_TEXT_CHARS // 2) + "]" * (MAX_TEXT_CHARS // 2))  # under the cap, still too deep
        error, _, _ = until(ws, "error")
        assert error["error"] == "bad_json" and "nested too deeply" in error["detail"]
        ws.send_text(json.dumps({**VIEW, "id": 1}))
        assert until(ws, "frame")[0]["id"] == 1


def test_deep_text_or_header_on_the_live_socket_is_answered_not_dropped(stream_client, take):
    rig_id = add_rig(stream_client, take)
    with stream_client.websocket_connect(f"/v1/rigs/{rig_id}/live") as live:
        until(live, "hello")
        head = ("[" * 30000 + "]" * 30000).encode()
        live.send_bytes(len(head).to_bytes(4, "big") + head)
        error, _, _ = until(live, "error")
        assert error["error"] == "bad_frame_set" and "nested too deeply" in error["detail"]
        live.send_bytes(frame_set([jpeg(b) for b in take.backgrounds], background=True, seq=1))
        assert until(live, "ack")[0]["seq"] == 1  # the socket still works
        live.send_text(DEEP)
        with pytest.raises(WebSocketDisconnect) as closed:
            until(live, "ack")
        assert closed.value.code == 1003  # a close frame with a code, as for any text but a ping
