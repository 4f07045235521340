"""Capture times: when each frame was taken, on one clock for the whole rig (seconds since the Unix epoch).

Three sources, best first:

- ``camera``: the camera's own wall clock, where the stream carries it. RTSP does, in its RTCP sender reports (each
  maps the camera's NTP clock to its RTP timestamps); FFmpeg applies the latest report to every packet as its
  *producer reference time* (``prft`` side data, microseconds since the epoch), which is what a reader reads.
  Cameras synchronised by NTP or PTP then agree to a millisecond or so; a camera whose clock is off by a known
  amount gets a per-camera offset.
- ``file``: a file played at its own frame rate: its timestamps on the player's clock.
- ``arrival``: the stream's own timestamps (pts; a V4L2 buffer's timestamp) anchored at arrival: each frame's
  capture time is its stream time plus the smallest (arrival - stream time) seen within a sliding window
  (:class:`ArrivalAnchor`): the least-delayed frame of the window, so network and decoder jitter do not move it, and
  the window lets it follow a camera clock that runs faster or slower than ours (drift). Without any timestamps,
  the arrival itself.
"""
from __future__ import annotations

import collections
import statistics
from dataclasses import dataclass
from typing import Literal

ClockKind = Literal["camera", "file", "arrival"]
JUMP_S = 1.0
"""A stream whose (arrival - stream time) moves by more than this restarted its timestamps: the anchor starts anew."""


def prft_seconds(side_data: bytes) -> float:
    """The wall clock of FFmpeg's producer reference time side data (``AVProducerReferenceTime``: int64 wallclock in
    microseconds since the Unix epoch, little-endian, then int32 flags), in seconds."""
    return int.from_bytes(side_data[:8], "little", signed=True) / 1e6


class ArrivalAnchor:
    """Capture times from a stream's own timestamps anchored at arrival (module docstring): a sliding-window
    minimum of (arrival - stream time) over ``window_s`` seconds of arrivals."""

    def __init__(self, window_s: float = 10.0) -> None:
        self.window_s = window_s
        self._window: collections.deque[tuple[float, float]] = collections.deque()  # (arrival, offset), offsets rising

    def stamp(self, stream_time: float, arrival: float) -> float:
        """The capture time (s since the epoch) of a frame with stream time ``stream_time`` (s, any origin) that
        arrived at ``arrival`` (s since the epoch)."""
        offset = arrival - stream_time
        if self._window and abs(offset - self._window[0][1]) > JUMP_S + self.window_s * 1e-3:
            self._window.clear()  # a new stream (reconnect, a file looping) or a clock step
        while self._window and self._window[-1][1] >= offset:
            self._window.pop()
        self._window.append((arrival, offset))
        while self._window[0][0] < arrival - self.window_s:
            self._window.popleft()
        return stream_time + self._window[0][1]

    def reset(self) -> None:
        self._window.clear()


@dataclass
class CaptureClock:
    """One camera's capture times: from whichever source a frame brings (module docstring), plus ``offset_s``, this
    camera's correction (seconds added to every capture time: a camera whose clock runs 40 ms ahead gets -0.040).
    Also keeps, for the status line, the kind of clock used last and how far capture times lie behind arrival."""

    offset_s: float = 0.0
    window_s: float = 10.0

    def __post_init__(self) -> None:
        self.anchor = ArrivalAnchor(self.window_s)
        self.kind: ClockKind = "arrival"
        self._delays: collections.deque[float] = collections.deque(maxlen=50)

    def stamp(self, arrival: float, camera_time: float | None = None, stream_time: float | None = None,
              file_time: float | None = None) -> float:
        """The capture time (s since the epoch, offset applied) of a frame that arrived at ``arrival``: from
        ``camera_time`` (the camera's wall clock, s since the epoch), else ``file_time`` (a played file's clock),
        else ``stream_time`` (the stream's own timestamps, s, any origin) anchored at arrival, else ``arrival``."""
        if camera_time is not None:
            self.kind, capture = "camera", camera_time
        elif file_time is not None:
            self.kind, capture = "file", file_time
        elif stream_time is not None:
            self.kind, capture = "arrival", self.anchor.stamp(stream_time, arrival)
        else:
            self.kind, capture = "arrival", arrival
        capture += self.offset_s
        self._delays.append(arrival - capture)
        return capture

    def restart(self) -> None:
        """A new connection: its stream timestamps start anew."""
        self.anchor.reset()

    @property
    def delay_ms(self) -> float | None:
        """Median of (arrival - capture time) over the last 50 frames, ms: transport and decoding delay, plus the
        camera clock's offset from ours where the camera's clock is used; None before any frame."""
        return statistics.median(self._delays) * 1e3 if self._delays else None
