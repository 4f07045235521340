"""``sweepcast live`` end to end: RTSP cameras served by the tests (harness/rtsp_camera.py), the capture side
reading them through PyAV, the service (uvicorn in this process) taking the sets. Every camera draws its trigger
index into its picture, so a set's frames say which instant each came from. Small frames and seconds-long runs:
the full ten 640x480 cameras at 25 fps are benchmarks/live_ingest.py's."""
from __future__ import annotations

import io
import json
import threading
import time

import cv2
import httpx
import numpy as np
import pytest
import websockets.sync.client as wsclient
import websockets.sync.server as wsserver

from app.capture.clocks import CaptureClock
from app.capture.live import LiveRun
from app.capture.mailbox import FrameMailbox
from app.capture.readers import CameraReader
from app.capture.settings import CaptureSettings
from app.capture.sources import Source
from harness.rtsp_camera import Camera, RtspServer, SilentServer, draw_instant, read_instant
from harness.servers import serve_in_thread
from harness.takes import rig_json
from workers.streaming.demo import demo_rig
from workers.streaming.framing import unpack_message
from workers.streaming.video import H264Writer

SIZE = (128, 96)
FPS = 25.0


@pytest.fixture(scope="module")
def service(ray_local, tmp_path_factory):
    from app.settings import Settings

    settings = Settings(data_dir=tmp_path_factory.mktemp("live") / "data", demo_rig=False, fetch_models=False,
                        session_idle_seconds=5.0)
    with serve_in_thread(settings) as base:
        yield base


def new_rig(base: str, cameras: int) -> tuple[str, list[str]]:
    rig = demo_rig(cameras, SIZE)
    with httpx.Client(base_url=base, timeout=30) as http:
        r = http.post("/v1/rigs", files={"files": ("rig.json", rig_json(rig))})
        assert r.status_code == 201, r.text
    return r.json()["id"], rig.names


class Relay:
    """The rig's live sets as the service relays them to a browser viewer: (time received, header, the trigger index
    read from each camera's picture), collected on a thread."""

    def __init__(self, base: str, rig_id: str) -> None:
        self.url = f"{base.replace('http', 'ws')}/v1/rigs/{rig_id}/view?source=live&render=browser"
        self.sets: list[tuple[float, dict, list[int]]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> "Relay":
        self._ws = wsclient.connect(self.url, max_size=None)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._ws.close()
        self._thread.join(10)

    def _run(self) -> None:
        try:
            for message in self._ws:
                if isinstance(message, str):
                    continue
                header, payload = unpack_message(message)
                offset, instants = 0, []
                for size in header["sizes"]:
                    image = cv2.imdecode(np.frombuffer(bytes(payload[offset:offset + size]), np.uint8), cv2.IMREAD_COLOR)
                    offset += size
                    instants.append(read_instant(image))
                self.sets.append((time.time(), header, instants))
        except Exception:  # noqa: BLE001 - the socket closed at the end of the test
            pass

    def wait(self, predicate, timeout: float, what: str) -> tuple[float, dict, list[int]]:
        deadline = time.monotonic() + timeout
        seen = 0
        while time.monotonic() < deadline:
            for item in self.sets[seen:]:
                if predicate(item):
                    return item
            seen = len(self.sets)
            time.sleep(0.05)
        raise AssertionError(f"no relayed set {what} within {timeout} s; last: {self.sets[-1][1] if self.sets else None}")


def started(run: LiveRun) -> threading.Thread:
    thread = threading.Thread(target=run.run, daemon=True)
    thread.start()
    return thread


def test_ten_rtsp_cameras_make_sets_of_one_instant_despite_clock_offsets_and_jitter(service):
    """Ten cameras at 25 fps triggered together (+-2 ms), each stamping frames with its own clock (RTCP sender
    reports), two of them far off and corrected with --offset, and up to 30 ms of network jitter: every set the
    service gets holds one trigger instant, its spread within the tolerance (half a frame period)."""
    rig_id, names = new_rig(service, 10)
    skew = {names[2]: 0.25, names[7]: -0.4}  # their clocks run 250 ms ahead, 400 ms behind
    cams = [Camera(n, *SIZE, fps=FPS, clock_offset=skew.get(n, 0.0), capture_jitter=0.002,
                   network_jitter=0.03 if i % 3 == 0 else 0.005, seed=i) for i, n in enumerate(names)]
    out = io.StringIO()
    with RtspServer(cams) as rtsp, Relay(service, rig_id) as relay:
        run = LiveRun.open(service, rig_id, [rtsp.url(n) for n in names], offset_args=[f"{n}={-s * 1e3:g}" for n, s in skew.items()],
                           out=out, status_every=1.0)
        thread = started(run)
        try:  # the first set waits for the rig's session to start: seconds on a loaded machine
            relay.wait(lambda s: len(relay.sets) >= 30, 60, "after 30 sets")
        except AssertionError:
            raise AssertionError(out.getvalue()) from None
        finally:
            run.stop()
            thread.join(15)
    whole = [(h, ks) for _, h, ks in relay.sets if not h["stale"]]
    assert len(whole) >= 15, out.getvalue()
    for header, instants in whole:
        assert len(set(instants)) == 1, (header, instants)  # one instant: every camera's frame of the same trigger
        assert header["spread_ms"] <= 20.5 and header["captured"] is not None
    triggers = [ks[0] for _, ks in whole]
    assert triggers == sorted(triggers) and len(set(triggers)) == len(triggers)
    assert all(r.clock.kind == "camera" for r in run.readers)  # the cameras' own clocks, from RTCP
    assert run.uplink.errors == {} and run.assembler.tolerance == pytest.approx(0.02, abs=0.002)
    status = out.getvalue()
    assert "spread p50" in status and "camera clock" in status and names[9] in status


def test_a_camera_stopped_and_restarted_goes_stale_meanwhile_and_is_back_within_seconds(service):
    """Three cameras (one with its clock 300 ms ahead, corrected); one stops: after missing_seconds the sets go on with
    it stale and the viewer renders on; when it returns it is in the sets again within 5 s, of the same instants."""
    rig_id, names = new_rig(service, 3)
    cams = [Camera(n, *SIZE, fps=FPS, clock_offset=0.3 if i == 1 else 0.0, capture_jitter=0.002, network_jitter=0.01,
                   seed=i) for i, n in enumerate(names)]
    out = io.StringIO()
    settings = CaptureSettings(missing_seconds=0.5)
    with RtspServer(cams) as rtsp, Relay(service, rig_id) as relay:
        run = LiveRun.open(service, rig_id, [rtsp.url(n) for n in names], offset_args=[f"{names[1]}=-300"],
                           settings=settings, out=out, status_every=1.0)
        thread = started(run)
        try:
            relay.wait(lambda s: not s[1]["stale"], 30, "with every camera")
            cams[1].stop()
            gone = time.time()
            relay.wait(lambda s: s[0] > gone and s[1]["stale"] == [names[1]], 10, f"with {names[1]} stale")
            with wsclient.connect(f"{service.replace('http', 'ws')}/v1/rigs/{rig_id}/view?source=live",
                                  max_size=None) as viewer:  # a viewer rendering on the server meanwhile
                while json.loads(viewer.recv())["type"] != "ready":
                    pass
                seqs = set()
                for i in range(1, 30):
                    viewer.send(json.dumps({"id": i, "frame": "live", "width": 64, "height": 48, "planes": 12}))
                    while isinstance(reply := viewer.recv(), str):
                        assert json.loads(reply)["type"] != "error", reply
                    header, _ = unpack_message(reply)
                    assert header["stale"] == [names[1]]
                    seqs.add(header["seq"])
                    if len(seqs) >= 3:
                        break
                    time.sleep(0.1)
                assert len(seqs) >= 3  # new sets, rendered without the missing camera
            cams[1].start(rtsp.epoch)
            back = time.time()
            returned = relay.wait(lambda s: s[0] > back and not s[1]["stale"], 10, f"with {names[1]} back")
            assert returned[0] - back < 5.0
        finally:
            run.stop()
            thread.join(15)
    whole = [ks for _, h, ks in relay.sets if not h["stale"]]
    assert whole and all(len(set(ks)) == 1 for ks in whole), whole
    assert run.readers[1].reconnects >= 1
    events = out.getvalue()
    assert f"{names[1]}: back" in events and f"{names[1]}: rtsp://" in events and "MISSING" in events


def test_a_source_that_never_answers_is_named_and_the_others_go_on(service):
    """One source accepts the connection and never answers; the two others send no sender reports (their own
    timestamps are anchored at arrival) and make the sets meanwhile, with the silent camera stale."""
    rig_id, names = new_rig(service, 3)
    cams = [Camera(n, *SIZE, fps=FPS, sender_reports=False, network_jitter=0.01, seed=i)
            for i, n in enumerate(names[:2])]
    out = io.StringIO()
    settings = CaptureSettings(missing_seconds=0.5, open_timeout_seconds=1.0, read_timeout_seconds=1.0)
    with RtspServer(cams) as rtsp, SilentServer() as silent, Relay(service, rig_id) as relay:
        run = LiveRun.open(service, rig_id, [rtsp.url(names[0]), rtsp.url(names[1]), silent.url()],
                           settings=settings, out=out, status_every=1.0)
        thread = started(run)
        try:
            relay.wait(lambda s: s[1]["stale"] == [names[2]], 30, f"with {names[2]} stale")
            time.sleep(1.0)
        finally:
            run.stop()
            thread.join(15)
    assert run.readers[0].clock.kind == run.readers[1].clock.kind == "arrival"
    # arrival anchoring is as exact as the least-delayed frame of the window: on a loaded machine a reader that
    # lags a frame behind stamps that frame late, so here the instants may be one trigger apart, never more
    pairs = [ks[:2] for _, h, ks in relay.sets if h["stale"] == [names[2]]]
    assert pairs and all(abs(a - b) <= 1 for a, b in pairs), pairs
    events = out.getvalue()
    assert f"{names[2]}: {silent.url()}: no answer" in events, events
    assert names[0] not in events.split("no answer")[0].splitlines()[-1]
    assert run.readers[0].error is None and run.readers[2].frames == 0


def test_the_status_says_when_sets_wait_for_a_service_that_does_not_acknowledge(tmp_path):
    """A service that takes the uplink and never acknowledges a set: after ``in_flight`` sets the status line says
    the service is what the sets wait for (not the cameras' spread), and the readers go on."""
    path = tmp_path / "clip.mp4"
    writer = H264Writer(path, *SIZE, fps=25)
    for k in range(10):
        writer.write(np.full((SIZE[1], SIZE[0], 3), 20 * k, np.uint8))
    writer.close()
    hello = {"type": "hello", "cameras": [{"name": n, "width": SIZE[0], "height": SIZE[1]} for n in ("a", "b")]}

    def silent_service(ws) -> None:
        ws.send(json.dumps(hello))
        for _ in ws:
            pass

    out = io.StringIO()
    with wsserver.serve(silent_service, "127.0.0.1", 0) as server:
        threading.Thread(target=server.serve_forever, daemon=True).start()
        run = LiveRun.open(f"http://127.0.0.1:{server.socket.getsockname()[1]}", "rig", [str(path)] * 2,
                           settings=CaptureSettings(in_flight=2), out=out, status_every=0.5)
        run.run(seconds=2.0)
        server.shutdown()
    assert run.uplink.sent == 2 and run.uplink.dropped > 10 and run.uplink.acked == 0
    last = [line for line in out.getvalue().splitlines() if line.startswith("live ")][-1]
    assert "sets 0.0/s  waiting for the service: 2 sets unacknowledged, the oldest for" in last, out.getvalue()
    assert "no instant within the tolerance" not in last and all(r.fps > 20 for r in run.readers)


def test_a_file_plays_at_its_own_rate_over_and_over(tmp_path):
    path = tmp_path / "clip.mp4"
    writer = H264Writer(path, *SIZE, fps=10)
    for k in range(5):
        image = np.full((SIZE[1], SIZE[0], 3), 90, np.uint8)
        draw_instant(image, k)
        writer.write(image)
    writer.close()
    box = FrameMailbox(keep=64)
    reader = CameraReader(Source(0, "clip", "file", str(path)), SIZE, CaptureClock(), box, CaptureSettings())
    reader.start()
    time.sleep(1.6)
    reader.stop()
    frames = box.recent()
    assert 12 <= len(frames) <= 18 and reader.clock.kind == "file"  # 10 fps for 1.6 s: looped three times
    assert np.diff([f.capture for f in frames]) == pytest.approx(0.1, abs=1e-3)
    assert [read_instant(f.bgr()) for f in frames[:7]] == [0, 1, 2, 3, 4, 0, 1]


def test_a_source_of_the_wrong_size_is_refused_with_a_reason(tmp_path):
    path = tmp_path / "big.mp4"
    writer = H264Writer(path, 64, 48, fps=10)
    writer.write(np.zeros((48, 64, 3), np.uint8))
    writer.close()
    said: list[str] = []
    reader = CameraReader(Source(0, "cam0", "file", str(path)), SIZE, CaptureClock(), FrameMailbox(),
                          CaptureSettings(), said.append)
    reader.start()
    time.sleep(0.5)
    reader.stop()
    assert reader.frames == 0 and said and "sends 64x48 frames; the rig's calibration of this camera is for 128x96" in said[0]
