"""One reader per camera: a thread that opens its source, decodes every frame, stamps it with its capture time
and puts it in the camera's mailbox; when the source cannot be opened, stops or misbehaves it says which camera and
why, waits (0.25 s, doubling up to ``max_backoff_seconds``) and opens it again, for as long as ``sweepcast live``
runs.

Threads, not processes, measured (``python -m benchmarks.live_ingest --only readers``: ten 640x480 H.264 cameras at
25 fps, two rounds on 2 cores, the machine otherwise idle): a process per camera, each converting its frames to BGR
into shared memory for the parent to copy out, delivered the same 250 frames/s for 1.06 times the CPU (0.61 against
0.58 cores) and 5.7 times the memory (about 95 MB a process: 1.19 GB in all against 0.21 GB). PyAV and OpenCV decode
with the GIL released, so ten reader threads decode on every core, and a frame reaches the assembler without a copy.
The processes' newest frame was younger when a set was taken (p95 57 against 61 ms) only because they convert each
frame as they decode it: threads that do the same were as young (56 ms) for less CPU (0.53 cores). Here a
frame is converted when a set takes it (:class:`~app.capture.mailbox.Frame`), so frames no set uses, when sets are
slower than the cameras, cost nothing. Each reader decodes on its own thread alone (no FFmpeg worker threads), so its
CPU time (``cpu_seconds``) is what the camera costs to demux and decode (``benchmarks/live_ingest.py`` reports it per
camera).
"""
from __future__ import annotations

import threading
import time
from typing import Any, Callable, Iterator

import av
import cv2

from .clocks import CaptureClock, prft_seconds
from .mailbox import Frame, FrameMailbox
from .settings import CaptureSettings
from .sources import Source, SourceError, device_path

FPS_WINDOW_S = 2.0
PROBE_US = 200_000


class CameraReader:
    """The reader of ``source`` (see the module docstring). ``size``: the (width, height) the rig's calibration of
    this camera is for; frames of another size are refused with a message. ``report(message)`` is told of every
    failure and return. Counters for the status line: ``frames``, ``reconnects`` (opened again after a failure),
    ``state``, ``error`` (the last failure), ``cpu_seconds`` (the thread's CPU time: decoding and stamping)."""

    def __init__(self, source: Source, size: tuple[int, int], clock: CaptureClock, mailbox: FrameMailbox,
                 settings: CaptureSettings, report: Callable[[str], None] = lambda message: None) -> None:
        self.source = source
        self.size = size
        self.clock = clock
        self.mailbox = mailbox
        self.settings = settings
        self.report = report
        self.frames = 0
        self.reconnects = 0
        self.state = "starting"
        self.error: str | None = None
        self.cpu_seconds = 0.0
        self._arrivals: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"reader-{source.name}", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop_soon(self) -> None:
        """Ask the thread to end (it does after the frame or wait it is in)."""
        self._stop.set()

    def stop(self, timeout: float = 5.0) -> None:
        self.stop_soon()
        self._thread.join(timeout)

    @property
    def fps(self) -> float:
        """Frames decoded per second over the last two seconds."""
        now = time.time()
        return sum(1 for t in self._arrivals if now - t <= FPS_WINDOW_S) / FPS_WINDOW_S

    # --- the loop ------------------------------------------------------------------------------------------
    def _run(self) -> None:
        backoff, failed = 0.25, False
        while not self._stop.is_set():
            self.state = "connecting"
            streamed = False
            opened_at = time.monotonic()
            try:
                for picture, stamps in self._read():
                    if not streamed:
                        streamed = True
                        backoff = 0.25
                        if failed:
                            self.reconnects += 1
                            self.report(f"{self.source.name}: back ({self.source.shown})")
                        failed, self.state, self.error = False, "streaming", None
                    self._take(picture, stamps)
                    if self._stop.is_set():
                        return
                if self._stop.is_set():
                    return
                raise SourceError("the stream ended")
            except Exception as exc:  # noqa: BLE001 - any failure of a source is reported and retried
                if self._stop.is_set():
                    return
                failed = True
                silent = not streamed and time.monotonic() - opened_at >= 0.9 * self.settings.open_timeout_seconds
                self.error = _reason(exc, self.settings, silent)
                self.state = f"retrying in {backoff:g} s"
                self.report(f"{self.source.name}: {self.source.shown}: {self.error}; trying again in {backoff:g} s")
            self._stop.wait(backoff)
            backoff = min(backoff * 2, self.settings.max_backoff_seconds)

    def _take(self, picture: Any, stamps: dict[str, float]) -> None:
        width, height = (picture.shape[1], picture.shape[0]) if hasattr(picture, "shape") else (picture.width, picture.height)
        if (width, height) != self.size:
            raise SourceError(f"sends {width}x{height} frames; the rig's calibration of this camera is for "
                              f"{self.size[0]}x{self.size[1]}")
        arrival = stamps.pop("arrival")
        capture = self.clock.stamp(arrival, **stamps)
        self.frames += 1
        self._arrivals = [t for t in self._arrivals if arrival - t <= FPS_WINDOW_S] + [arrival]
        self.mailbox.put(Frame(self.source.camera, picture, capture, arrival, self.frames))
        self.cpu_seconds = time.thread_time()

    def _read(self) -> Iterator[tuple[Any, dict[str, float]]]:
        """(picture, stamps) per decoded frame: stamps has ``arrival`` and the clock source the frame brings
        (:meth:`CaptureClock.stamp`'s keywords)."""
        self.clock.restart()
        if self.source.kind == "v4l2":
            yield from self._read_device()
        elif self.source.kind == "file":
            yield from self._read_file()
        else:
            yield from self._read_network()

    def _read_network(self) -> Iterator[tuple[Any, dict[str, float]]]:
        options = {}
        if self.source.target.startswith("rtsp"):
            # an RTSP camera describes its stream (SDP: codec, size, parameter sets): 0.2 s of probing is enough, and
            # a camera coming back is streaming 0.3 s after it answers instead of FFmpeg's default 1.2 s
            options = {"rtsp_transport": self.settings.rtsp_transport, "analyzeduration": str(PROBE_US)}
        with av.open(self.source.target, options=options,
                     timeout=(self.settings.open_timeout_seconds, self.settings.read_timeout_seconds)) as container:
            stream = _video_stream(container)
            camera_times: dict[int, float] = {}
            for packet in container.demux(stream):
                arrival = time.time()
                prft = packet.get_sidedata("prft")
                camera_time = prft_seconds(bytes(prft)) if prft else None
                if camera_time is not None and packet.pts is not None:
                    camera_times[packet.pts] = camera_time  # a decoder that reorders gives frames of earlier packets
                for frame in packet.decode():
                    own = camera_times.pop(frame.pts, camera_time) if frame.pts is not None else camera_time
                    stream_time = float(frame.time) if frame.time is not None else None
                    yield frame, {"arrival": arrival, "camera_time": own, "stream_time": stream_time}
                if len(camera_times) > 64:
                    camera_times.clear()

    def _read_file(self) -> Iterator[tuple[Any, dict[str, float]]]:
        """The file at its own frame rate, from its start again at its end; capture times on the player's clock."""
        base = time.time()
        while not self._stop.is_set():
            played = 0
            with av.open(self.source.target) as container:
                stream = _video_stream(container)
                period = 1.0 / float(stream.average_rate or 25)
                first = None
                last = base
                for frame in container.decode(stream):
                    t = float(frame.time) if frame.time is not None else played * period
                    first = t if first is None else first
                    last = base + t - first
                    if self._stop.wait(max(0.0, last - time.time())):
                        return
                    played += 1
                    yield frame, {"arrival": time.time(), "file_time": last}
            if not played:
                raise SourceError("the file holds no video frames")
            base = last + period

    def _read_device(self) -> Iterator[tuple[Any, dict[str, float]]]:
        path = device_path(self.source.target)
        capture = cv2.VideoCapture(path, cv2.CAP_V4L2)
        try:
            if not capture.isOpened():
                raise SourceError(f"cannot open {path} (no such device, in use by another program, or no permission)")
            capture.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*"MJPG"))  # what USB cameras send at full rate
            capture.set(cv2.CAP_PROP_FRAME_WIDTH, self.size[0])
            capture.set(cv2.CAP_PROP_FRAME_HEIGHT, self.size[1])
            capture.set(cv2.CAP_PROP_BUFFERSIZE, 1)
            while not self._stop.is_set():
                ok, image = capture.read()
                arrival = time.time()
                if not ok:
                    raise SourceError(f"{path} stopped delivering frames")
                stamp = capture.get(cv2.CAP_PROP_POS_MSEC)  # the driver's buffer timestamp (monotonic clock), ms
                yield image, {"arrival": arrival, "stream_time": stamp / 1e3 if stamp > 0 else None}
        finally:
            capture.release()


def _video_stream(container: Any) -> Any:
    if not container.streams.video:
        raise SourceError("the source has no video stream")
    stream = container.streams.video[0]
    # one decoding thread, the reader's own: a rig runs a reader per camera already (more threads only contend for
    # the same cores), frame threading would hold frames back, and the reader's CPU time is then all of its decoding
    stream.codec_context.thread_count = 1
    return stream


def _reason(exc: BaseException, settings: CaptureSettings, silent: bool = False) -> str:
    """What went wrong, in a user's words; ``silent``: the source had not sent a frame when its open timeout ran
    out (FFmpeg then reports whatever it was waiting for, often "Invalid data found")."""
    if isinstance(exc, SourceError):
        return str(exc)
    text = (getattr(exc, "strerror", None) if isinstance(exc, av.FFmpegError) else None) or str(exc).strip() \
        or type(exc).__name__
    if silent:
        return f"no answer within {settings.open_timeout_seconds:g} s ({text})"
    if isinstance(exc, av.ExitError):  # FFmpeg's interrupt: the read timeout ran out mid-stream
        return f"nothing received for {settings.read_timeout_seconds:g} s ({text})"
    return text
