"""Live sets by capture time at the service: each set's spread is reported, a set spread over its tolerance is
never rendered as one instant, and a camera gone missing (stale) is left out while the viewers render on."""
from __future__ import annotations

import json
import time

import pytest

from harness.takes import frame_set, jpeg
from tests.streaming.conftest import add_rig
from tests.streaming.test_sockets import VIEW, until
from workers.streaming.framing import FramingError, unpack_frame_set
from workers.streaming.session import LiveSession, SessionLimits, SetTiming, ViewError


def test_the_header_carries_capture_times_and_stale_cameras_in_rig_order():
    names = ["a", "b", "c"]
    message = frame_set([b"1", b"22", b"333"], cameras=["c", "a", "b"], captured=[3.0, 1.0, 2.0], stale=["b"],
                        tolerance=0.02)
    parsed = unpack_frame_set(message, names)
    assert parsed.captured == [1.0, 2.0, 3.0] and parsed.stale == [False, True, False] and parsed.tolerance == 0.02
    for bad, says in [({"captured": [1.0, 2.0]}, "'captured' must list 3"), ({"captured": [1, "x", 2]}, "'captured'"),
                      ({"stale": ["z"]}, r"unknown camera\(s\) z"), ({"tolerance": -1}, "'tolerance'"),
                      ({"stale": ["a", "b"]}, "at least two cameras")]:
        with pytest.raises(FramingError, match=says):
            unpack_frame_set(frame_set([b"1", b"22", b"333"], **bad), names)


def test_a_set_over_its_tolerance_or_the_service_limit_is_refused(take):
    live = LiveSession(take.rig, SessionLimits(max_spread=0.05))
    n = len(take.rig)
    jpegs = [jpeg(i) for i in take.frames[0]]
    live.push(jpegs, timing=SetTiming(tuple(100.0 + 0.001 * c for c in range(n)), (), 0.02))
    assert live.seq == 1 and live.timing()["spread_ms"] == pytest.approx((n - 1), abs=1e-6)
    for spread, tolerance in [(0.03, 0.02), (0.06, 0.5)]:  # over the client's tolerance; over the service's limit
        with pytest.raises(ViewError, match="spread_over_tolerance|captured") as caught:
            live.push(jpegs, timing=SetTiming((100.0,) + (100.0 + spread,) * (n - 1), (), tolerance))
        assert caught.value.code == "spread_over_tolerance"
    assert live.seq == 1  # nothing was shown
    stale = tuple(c == 0 for c in range(n))  # camera 0's old frame is far off: it is left out, so the set is fine
    live.push(jpegs, timing=SetTiming((90.0,) + (100.0,) * (n - 1), stale, 0.02))
    assert live.seq == 2 and live.timing()["stale"] == [take.rig.names[0]] and live.timing()["spread_ms"] == 0.0
    assert len(live.renderer.rig) == n - 1  # rendered without it


def test_the_live_socket_reports_spread_refuses_a_spread_set_and_renders_on_without_a_stale_camera(stream_client, take):
    client = stream_client
    rig_id = add_rig(client, take)
    names = take.rig.names
    n = len(names)
    t = time.time()
    with client.websocket_connect(f"/v1/rigs/{rig_id}/live") as live:
        until(live, "hello")
        live.send_bytes(frame_set([jpeg(b) for b in take.backgrounds], background=True, seq=1))
        until(live, "ack")
        live.send_bytes(frame_set([jpeg(i) for i in take.frames[0]], seq=2, tolerance=0.02,
                                  captured=[t + 0.002 * c for c in range(n)]))
        ack, _, _ = until(live, "ack")
        assert ack["spread_ms"] == pytest.approx(2.0 * (n - 1), abs=1e-3) and ack["stale"] == []
        assert ack["captured"] == pytest.approx(t + 0.001 * (n - 1), abs=1e-6)  # the set's instant: the median
        with client.websocket_connect(f"/v1/rigs/{rig_id}/view?source=live") as viewer:
            until(viewer, "ready")
            viewer.send_text(json.dumps({**VIEW, "id": 1, "frame": "live"}))
            header, _, _ = until(viewer, "frame")
            assert header["seq"] == 2 and header["spread_ms"] == ack["spread_ms"]  # the viewer shows it beside fps
            # frames of two instants (one camera 40 ms late, the tolerance 20 ms): refused, never rendered as one
            live.send_bytes(frame_set([jpeg(i) for i in take.frames[1]], seq=3, tolerance=0.02,
                                      captured=[t + 0.04] + [t] * (n - 1)))
            error, _, _ = until(live, "error")
            assert error["error"] == "spread_over_tolerance" and error["seq"] == 3 and "40.0 ms apart" in error["detail"]
            viewer.send_text(json.dumps({**VIEW, "id": 2, "frame": "live"}))
            assert until(viewer, "frame")[0]["seq"] == 2  # the previous set stays on show
            # a camera gone: its last frame comes marked stale; the view is rendered on from the others
            live.send_bytes(frame_set([jpeg(i) for i in take.frames[2]], seq=4, tolerance=0.02, stale=[names[1]],
                                      captured=[t + 0.08] * n))
            ack, _, _ = until(live, "ack")
            assert ack["stale"] == [names[1]] and ack["live_seq"] == 3
            viewer.send_text(json.dumps({**VIEW, "id": 3, "frame": "live"}))
            header, jpeg_bytes, _ = until(viewer, "frame")
            assert header["seq"] == 3 and header["stale"] == [names[1]] and header["coverage"] > 0.05 and jpeg_bytes
            info = [s for s in client.get("/v1/sessions").json()["sessions"] if s["rig_id"] == rig_id][0]["info"]
            assert info["stale"] == [names[1]] and info["spread_ms"] == 0.0


def test_a_client_without_capture_times_is_served_as_before(stream_client, take):
    rig_id = add_rig(stream_client, take)
    with stream_client.websocket_connect(f"/v1/rigs/{rig_id}/live") as live:
        until(live, "hello")
        live.send_bytes(frame_set([jpeg(i) for i in take.frames[0]], seq=1))
        ack, _, _ = until(live, "ack")
        assert ack["spread_ms"] is None and ack["captured"] is None and ack["stale"] == []

