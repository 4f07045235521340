"""The status of ``sweepcast live`` while it runs: one line for the sets, one per camera.

::

    live 42 s  sets 24.8/s  spread p50 1.2 ms  max 3.9 ms  (tolerance 20 ms)  acked 24.8/s  ack p50 38 ms
      cam0  25.0 fps  camera clock   +36 ms  drops  3  reconnects 0  streaming
      cam3   0.0 fps  arrival clock      -  drops  0  reconnects 1  MISSING 3.1 s (stale)  retrying in 2 s: ...

- sets: frame sets sent per second; *spread*: latest minus earliest capture time within a set (median and largest
  of the sets sent since the last line); *tolerance*: the largest spread a set may have; acked and the time from a
  set sent to its acknowledgement. When no set was sent since the last line, why: the service has not acknowledged
  the sets in flight (how many, the oldest for how long, and how many sets were dropped meanwhile: a service still
  starting the rig's session, or too slow), or no instant is within the tolerance (the smallest spread found).
- per camera: frames decoded per second; which clock stamps its frames (``camera``: the camera's own, from RTCP;
  ``file``: a file's; ``arrival``: the stream's timestamps anchored at arrival) and the median of arrival minus
  capture time (transport delay, plus the camera clock's offset from ours for a camera clock); *drops*: frames
  decoded and never sent in a set (the newest-frame policy at work when sets are slower than the camera);
  *reconnects*; the reader's state and last error; MISSING when its last frame is older than ``missing_seconds``
  (its frame goes in the sets marked stale).

On a terminal the block is redrawn in place every ``every`` seconds; otherwise it is printed every ``every``
seconds. Events (a camera lost or back, a set the service refused) are printed as lines of their own.
"""
from __future__ import annotations

import statistics
import sys
import threading
import time
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:
    from .live import LiveRun


class StatusLine:
    """Prints ``run``'s status block (module docstring) to ``out`` every ``every`` seconds on its own thread."""

    def __init__(self, run: "LiveRun", out: TextIO = sys.stderr, every: float | None = None) -> None:
        self.run = run
        self.out = out
        self.tty = bool(getattr(out, "isatty", lambda: False)())
        self.every = every if every is not None else (1.0 if self.tty else 10.0)
        self._drawn = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="status", daemon=True)
        self._last = (time.monotonic(), 0, 0, 0)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.print()

    def event(self, message: str) -> None:
        """A line of its own (above the block on a terminal)."""
        with self._lock:
            self._erase()
            self.out.write(f"{time.strftime('%H:%M:%S')} {message}\n")
            self.out.flush()

    def _loop(self) -> None:
        while not self._stop.wait(self.every):
            self.print()

    def print(self) -> None:
        lines = self.lines()
        with self._lock:
            self._erase()
            self.out.write("\n".join(lines) + "\n")
            self.out.flush()
            self._drawn = len(lines) if self.tty else 0

    def _erase(self) -> None:
        if self.tty and self._drawn:
            self.out.write(f"\x1b[{self._drawn}F\x1b[J")
            self._drawn = 0

    def lines(self) -> list[str]:
        """The block as text (module docstring)."""
        run = self.run
        now = time.monotonic()
        t0, sent0, acked0, dropped0 = self._last
        seconds = max(now - t0, 1e-6)
        sent, acked, dropped = run.uplink.sent, run.uplink.acked, run.uplink.dropped
        self._last = (now, sent, acked, dropped)
        spreads = run.take_spreads()
        waiting, oldest = run.uplink.unacknowledged()
        head = [f"live {now - run.started:.0f} s", f"sets {(sent - sent0) / seconds:.1f}/s"]
        if spreads:
            head.append(f"spread p50 {statistics.median(spreads) * 1e3:.1f} ms  max {max(spreads) * 1e3:.1f} ms")
        elif waiting >= run.uplink.settings.in_flight:  # the uplink is full: sets made are dropped
            head.append(f"waiting for the service: {waiting} sets unacknowledged, the oldest for {oldest:.1f} s "
                        f"({dropped - dropped0} dropped meanwhile)")
        elif run.assembler.best_failed_spread is not None:
            head.append(f"no instant within the tolerance: best spread {run.assembler.best_failed_spread * 1e3:.1f} ms")
        head.append(f"(tolerance {run.assembler.tolerance * 1e3:.0f} ms)" if run.assembler.tolerance < float("inf")
                    else "(tolerance: waiting for frame rates)")
        head.append(f"acked {(acked - acked0) / seconds:.1f}/s")
        if run.uplink.ack_ms:
            head.append(f"ack p50 {statistics.median(run.uplink.ack_ms):.0f} ms")
        if not run.uplink.connected:
            head.append("SERVICE DISCONNECTED")
        if run.uplink.errors:
            head.append("refused: " + ", ".join(f"{k} {v}" for k, v in run.uplink.errors.items()))
        lines = ["  ".join(head)]
        missing = run.assembler.missing()
        width = max(len(r.source.name) for r in run.readers)
        for i, reader in enumerate(run.readers):
            delay = reader.clock.delay_ms
            parts = [f"  {reader.source.name:<{width}}", f"{reader.fps:5.1f} fps", f"{reader.clock.kind:>7} clock",
                     f"{delay:+6.0f} ms" if delay is not None else "     - ms",
                     f"drops {max(0, reader.frames - run.assembler.used[i]):3d}", f"reconnects {reader.reconnects}"]
            if missing[i]:
                newest = run.mailboxes[i].newest()
                silent = time.time() - (newest.arrival if newest else run.started_wall)
                parts.append(f"MISSING {silent:.1f} s (stale)")
            parts.append(reader.state + (f": {reader.error}" if reader.error and reader.state != "streaming" else ""))
            lines.append("  ".join(parts))
        return lines
