"""Viewers sharing one session on a real socket: served in turn, nothing drawn for viewers that left, and a viewer
that stops reading is closed without holding up the others (TCP's own back-pressure, hence uvicorn, not the test
client)."""
from __future__ import annotations

import json
import logging
import os
import socket
import threading
import time

import httpx
import pytest
from websockets.sync.client import connect

from harness.servers import serve_in_thread, stalled_websocket
from harness.takes import frame_set, jpeg, rig_json, zip_bytes
from workers.streaming.framing import unpack_message

STALL_S = 1.0
SMALL = {"width": 96, "height": 72, "planes": 16}
MEDIUM = {"width": 192, "height": 144, "planes": 24}
"""Views whose drawing, not their way to and from the client, takes most of a turn."""
BIG = {"width": 320, "height": 240, "planes": 16, "quality": 95}
"""Frames of some 10-20 KB: a few fill the buffers of a reader that stopped."""


@pytest.fixture(scope="module")
def served(ray_local, tmp_path_factory, take):
    """One service for the module: one view drawn at a time, sockets that stall for STALL_S are closed; a rig
    with a ready recording. Yields (base URL, rig id)."""
    from app.settings import Settings

    settings = Settings(data_dir=tmp_path_factory.mktemp("sharing") / "data", demo_rig=False, fetch_models=False,
                        session_idle_seconds=5.0, session_render_slots=1, viewer_stall_seconds=STALL_S)
    with serve_in_thread(settings) as base, httpx.Client(base_url=base, timeout=30) as http:
        rig_id = http.post("/v1/rigs", files={"files": ("rig.json", rig_json(take.rig))}).json()["id"]
        rec = http.post(f"/v1/rigs/{rig_id}/recordings", files={"archive": ("t.zip", zip_bytes(take))}).json()
        while http.get(f"/v1/rigs/{rig_id}/recordings/{rec['id']}").json()["state"] == "processing":
            time.sleep(0.1)
        yield base, rig_id


def ws_url(base: str, path: str) -> str:
    return "ws" + base.removeprefix("http") + path


def opened(base: str, path: str):
    """A viewer socket past its ``ready`` message."""
    ws = connect(ws_url(base, path), open_timeout=30)
    while json.loads(ws.recv(timeout=60)).get("type") != "ready":
        pass
    return ws


def frame(ws) -> dict:
    """The header of the next frame (JSON messages on the way are skipped)."""
    while True:
        message = ws.recv(timeout=60)
        if isinstance(message, bytes):
            return unpack_message(message)[0]


def session_turns(base: str, rig_id: str) -> dict:
    """The turns counters and renders of the rig's recording session (renders 0 while there is none)."""
    sessions = httpx.get(f"{base}/v1/sessions", timeout=30).json()["sessions"]
    ours = [s for s in sessions if s["rig_id"] == rig_id and s["source"] != "live"]
    return {**ours[0]["info"].get("turns", {}), "renders": ours[0]["info"]["renders"]} if ours else {"renders": 0}


def test_viewers_of_one_session_are_served_in_turn(served):
    """Four viewers asking as fast as they can, a fifth joining: between two frames of any viewer every other
    viewer gets about one (round robin), and the newcomer waits for about one frame of each viewer; without
    turns a viewer could wait behind every other viewer's queued work, any number of rounds."""
    base, rig_id = served
    turns: dict[int, list[int]] = {}
    newcomer: dict[str, int] = {}
    seen = [0]
    lock = threading.Lock()

    def stream(index: int, frames: int, join_after: int = 0) -> None:
        ws = opened(base, f"/v1/rigs/{rig_id}/view")
        try:
            while join_after and seen[0] < join_after:
                time.sleep(0.01)
            for n in range(frames):
                with lock:
                    latest = seen[0]
                ws.send(json.dumps({**MEDIUM, "id": n, "orbit": {"azimuth": 3 * n - 10 * index}}))
                got = frame(ws)["turn"]
                with lock:
                    turns.setdefault(index, []).append(got)
                    seen[0] = max(seen[0], got)
                if n == 0 and join_after:
                    newcomer.update(asked_after=latest, turn=got)
        finally:
            ws.close()

    threads = [threading.Thread(target=stream, args=(i, 12)) for i in range(4)]
    threads.append(threading.Thread(target=stream, args=(4, 4, 16)))
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert sorted(len(v) for v in turns.values()) == [4, 12, 12, 12, 12]
    for index, got in turns.items():
        gaps = [b - a for a, b in zip(got, got[1:])]
        # one turn of each of the 4 others in between, and at most one more each while this viewer's next request
        # was on its way (a loaded machine can hold a client thread back for a whole round)
        assert max(gaps) <= 9, (index, got)
    # the newcomer's first turn: behind one request of each of the 4 others (+1 being drawn), with the same slack
    assert newcomer["turn"] - newcomer["asked_after"] <= 10, newcomer


def test_viewers_that_left_get_nothing_rendered(served):
    """Five viewers ask for a view while another's (large) view is drawn, then close: none of their views is
    drawn, and the session counts them as dropped."""
    base, rig_id = served
    keeper = opened(base, f"/v1/rigs/{rig_id}/view")
    before = session_turns(base, rig_id)
    leavers = [opened(base, f"/v1/rigs/{rig_id}/view") for _ in range(5)]
    keeper.send(json.dumps({"id": 1, "width": 960, "height": 720, "planes": 256}))  # a second or more to draw
    time.sleep(0.2)
    for n, ws in enumerate(leavers):
        ws.send(json.dumps({**SMALL, "id": n}))
    time.sleep(0.3)  # their requests are in line behind the keeper's
    for ws in leavers:
        ws.close()
    assert frame(keeper)["id"] == 1
    keeper.send(json.dumps({**SMALL, "id": 2}))
    assert frame(keeper)["id"] == 2
    keeper.close()
    after = session_turns(base, rig_id)
    assert after["renders"] - before["renders"] == 2  # the keeper's two views; none for the five that left
    assert after["dropped_for_gone"] - before["dropped_for_gone"] == 5
    assert after["drawn_for_gone"] == before["drawn_for_gone"] == 0



def text_frame(text: str) -> bytes:
    """One masked WebSocket text frame (a client's frames are masked), under 64 KiB."""
    payload, mask = text.encode(), os.urandom(4)
    size = bytes([0x80 | len(payload)]) if len(payload) < 126 else bytes([0x80 | 126]) + len(payload).to_bytes(2, "big")
    return b"\x81" + size + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload))


def until_cut_off(sock: socket.socket, message: bytes, limit_s: float = 30.0) -> float:
    """Send ``message`` every 20 ms until the server drops the connection; the time it did."""
    deadline = time.monotonic() + limit_s
    sock.settimeout(1.0)
    while time.monotonic() < deadline:
        try:
            sock.sendall(message)
        except OSError:
            return time.monotonic()
        time.sleep(0.02)
    raise AssertionError("the server kept a socket that reads nothing open")


def healthy_viewer(base: str, rig_id: str, stop: threading.Event, times: list[float]) -> None:
    ws = opened(base, f"/v1/rigs/{rig_id}/view")
    try:
        n = 0
        while not stop.is_set():
            ws.send(json.dumps({**SMALL, "id": n, "orbit": {"azimuth": n % 40 - 20}}))
            frame(ws)
            times.append(time.monotonic())
            n += 1
    finally:
        ws.close()


def stall_lines(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "stopped reading" in r.getMessage()]


def test_a_viewer_that_stops_reading_is_closed_and_holds_up_no_one(served, caplog):
    """A viewer that asks for views and never reads them: it gets a frame or two, then no more renders; it is
    closed after STALL_S (one log line) and cut off, and a viewer beside it keeps its frames all along."""
    base, rig_id = served
    caplog.set_level(logging.WARNING, logger="sweepcast.rigs")
    stop, times = threading.Event(), []
    before = session_turns(base, rig_id)["renders"]
    healthy = threading.Thread(target=healthy_viewer, args=(base, rig_id, stop, times))
    healthy.start()
    try:
        stalled = stalled_websocket(base, f"/v1/rigs/{rig_id}/view")
        cut_at = until_cut_off(stalled, text_frame(json.dumps({**BIG, "id": 1})))
        stalled.close()
        time.sleep(0.5)
    finally:
        stop.set()
        healthy.join(60)
    lines = stall_lines(caplog)
    assert len(lines) == 1 and lines[0].startswith("viewer socket from 127.0.0.1:"), lines
    # its frames stopped once its connection held one or two it had not taken, though it kept asking
    assert session_turns(base, rig_id)["renders"] - before - len(times) <= 4
    # while the stalled socket waited out its STALL_S and the close's grace, the healthy viewer got its frames
    assert sum(cut_at - 2.0 <= t <= cut_at for t in times) >= 3, (cut_at, times[-10:])
    assert times[-1] > cut_at


def test_a_browser_viewer_that_stops_reading_the_live_stream_is_closed(served, take, caplog):
    """A browser-rendering live viewer that never reads the frame sets relayed to it is closed and cut off; the
    live client's frame sets go on being applied."""
    base, rig_id = served
    caplog.set_level(logging.WARNING, logger="sweepcast.rigs")
    acks = []
    live = connect(ws_url(base, f"/v1/rigs/{rig_id}/live"), open_timeout=30)
    try:
        live.recv(timeout=60)  # hello
        stalled = stalled_websocket(base, f"/v1/rigs/{rig_id}/view?source=live&render=browser")
        sets = [[jpeg(image, 95) for image in images] for images in take.frames]
        done = threading.Event()

        def push() -> None:
            seq = 1
            while not done.is_set():
                live.send(frame_set(sets[seq % len(sets)], seq=seq))
                while json.loads(live.recv(timeout=60)).get("type") != "ack":
                    pass
                acks.append(time.monotonic())
                seq += 1

        pusher = threading.Thread(target=push)
        pusher.start()
        try:
            cut_at = until_cut_off(stalled, text_frame('{"type": "ping"}'))
            time.sleep(0.3)
        finally:
            done.set()
            pusher.join(60)
        stalled.close()
    finally:
        live.close()
    lines = stall_lines(caplog)
    assert len(lines) == 1 and lines[0].startswith("browser viewer socket from"), lines
    assert sum(cut_at - 2.0 <= t for t in acks) >= 3
