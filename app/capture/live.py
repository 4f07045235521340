"""``sweepcast live RIG SOURCE...``: the rig's cameras to its live socket, until stopped (Ctrl-C) or ``seconds``.

:class:`LiveRun` wires the parts: the uplink's hello names the rig's cameras (and their sizes), the sources are
matched to them, one reader per camera fills its mailbox, the assembler builds sets by capture time, the uplink
sends them, the status line says what happens.
"""
from __future__ import annotations

import collections
import statistics
import sys
import threading
import time
from typing import Sequence, TextIO

from .assembly import SetAssembler
from .clocks import CaptureClock
from .mailbox import FrameMailbox
from .readers import CameraReader
from .settings import CaptureSettings
from .sources import SourceError, parse_offsets, parse_sources
from .status import StatusLine
from .uplink import Uplink

UNKNOWN_TOLERANCE = float("inf")


class LiveRun:
    """One run of ``sweepcast live`` (module docstring). Built by :meth:`open`; :meth:`run` sends sets until
    :meth:`stop` or ``seconds``. ``background``: the first set sent is the empty scene (the background model the
    service's silhouettes come from); :meth:`take_background` flags the next one."""

    def __init__(self, uplink: Uplink, sources: Sequence, offsets: Sequence[float], settings: CaptureSettings,
                 out: TextIO = sys.stderr, status_every: float | None = None, background: bool = False) -> None:
        self.uplink = uplink
        self.settings = settings
        self.status = StatusLine(self, out, status_every)
        uplink.report = self.status.event
        self.arrived = threading.Event()
        self.mailboxes = [_NotifyingMailbox(settings.keep_frames, self.arrived) for _ in sources]
        sizes = [(c["width"], c["height"]) for c in uplink.cameras]
        self.readers = [CameraReader(s, sizes[s.camera], CaptureClock(offsets[s.camera], settings.drift_window_seconds),
                                     self.mailboxes[s.camera], settings, self.status.event) for s in sources]
        tolerance = settings.tolerance_ms / 1e3 if settings.tolerance_ms else UNKNOWN_TOLERANCE
        self.assembler = SetAssembler(self.mailboxes, tolerance, settings.missing_seconds)
        self.fixed_tolerance = settings.tolerance_ms is not None
        self.started = time.monotonic()
        self.started_wall = time.time()
        self._spreads: collections.deque[float] = collections.deque(maxlen=10_000)
        self.history: collections.deque[tuple[float, float, tuple[bool, ...]]] = collections.deque(maxlen=100_000)
        """(time sent, s since the epoch; spread, s; stale per camera) of every set sent."""
        self._background = background
        self._stop = threading.Event()

    @classmethod
    def open(cls, server: str, rig_id: str, source_args: Sequence[str], key: str | None = None,
             offset_args: Sequence[str] = (), settings: CaptureSettings | None = None, out: TextIO = sys.stderr,
             status_every: float | None = None, background: bool = False) -> "LiveRun":
        """Connect to the service and match the sources to the rig's cameras: UplinkError or SourceError (the
        message says what is wrong) before any camera is opened."""
        settings = settings or CaptureSettings()
        uplink = Uplink(server, rig_id, key, settings)
        uplink.open()
        try:
            names = [c["name"] for c in uplink.cameras]
            sources = parse_sources(source_args, names)
            offsets = parse_offsets(offset_args, names)
        except SourceError:
            uplink.close()
            raise
        return cls(uplink, sources, offsets, settings, out, status_every, background)

    def take_background(self) -> None:
        """The next set sent is flagged as the empty scene."""
        self._background = True

    def take_spreads(self) -> list[float]:
        """The spreads (s) of the sets sent since the last call."""
        out = list(self._spreads)
        self._spreads.clear()
        return out

    def stop(self) -> None:
        self._stop.set()
        self.arrived.set()

    def run(self, seconds: float | None = None) -> None:
        """Send sets until :meth:`stop` or ``seconds``; then stop the readers and the uplink."""
        for reader in self.readers:
            reader.start()
        self.status.start()
        deadline = time.monotonic() + seconds if seconds is not None else float("inf")
        try:
            while not self._stop.is_set() and time.monotonic() < deadline:
                self.arrived.wait(0.05)
                self.arrived.clear()
                if not self.fixed_tolerance:
                    self.assembler.tolerance = self._measured_tolerance()
                frame_set = self.assembler.next_set()
                if frame_set is None:
                    continue
                if self.uplink.send(frame_set, self.assembler.tolerance, self._background):
                    self._background = False
                    self._spreads.append(frame_set.spread)
                    self.history.append((time.time(), frame_set.spread, tuple(frame_set.stale)))
        finally:
            for reader in self.readers:
                reader.stop_soon()
            for reader in self.readers:
                reader.stop()
            self.status.stop()
            self.uplink.close()

    def _measured_tolerance(self) -> float:
        """Half the frame period of the slowest camera present (the median interval between its newest capture
        times), once each camera present has sent three frames; until then unknown (no set). A missing camera
        counts for nothing: one that never answers does not hold the others up."""
        periods = []
        for box, missing in zip(self.mailboxes, self.assembler.missing()):
            times = [f.capture for f in box.recent()]
            if missing:
                continue
            if len(times) < 3:
                return self.assembler.tolerance
            periods.append(statistics.median(b - a for a, b in zip(times, times[1:])))
        return max(periods) / 2 if periods else self.assembler.tolerance


class _NotifyingMailbox(FrameMailbox):
    """A mailbox that wakes the assembler when a frame arrives."""

    def __init__(self, keep: int, arrived: threading.Event) -> None:
        super().__init__(keep)
        self._arrived = arrived

    def put(self, frame) -> None:
        super().put(frame)
        self._arrived.set()
