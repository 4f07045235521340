"""Terminal output for the CLI verbs: a progress bar on stderr and aligned tables."""
from __future__ import annotations

import sys
import time
from typing import Sequence, TextIO

from workers.common.pace import describe_seconds


class ProgressBar:
    """A single-line progress bar on a terminal (plain lines when not a TTY).

    Use as a callback: ``bar(fraction, stage)`` with ``fraction`` in [0, 1], and ``eta_s`` the seconds still to go
    where the caller knows them (:class:`workers.common.pace.Pace`).
    """

    def __init__(self, label: str = "", stream: TextIO | None = None, width: int = 30) -> None:
        self.label = label
        self.stream = stream or sys.stderr
        self.width = width
        self.start = time.perf_counter()
        self._last_stage = None
        self._tty = hasattr(self.stream, "isatty") and self.stream.isatty()

    def __call__(self, fraction: float, stage: str = "", eta_s: float | None = None) -> None:
        fraction = min(max(float(fraction), 0.0), 1.0)
        elapsed = time.perf_counter() - self.start
        left = "" if eta_s is None else f" ETA {describe_seconds(eta_s)}"
        if self._tty:
            filled = int(round(fraction * self.width))
            bar = "#" * filled + "-" * (self.width - filled)
            self.stream.write(f"\r{self.label} [{bar}] {fraction:5.1%} {elapsed:6.1f}s{left} {stage[:40]:<40}")
            self.stream.flush()
        elif stage != self._last_stage:
            self.stream.write(f"{self.label} {fraction:5.1%} {elapsed:6.1f}s{left} {stage}\n")
            self._last_stage = stage

    def close(self) -> None:
        if self._tty:
            self.stream.write("\n")
            self.stream.flush()


def format_table(headers: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """Rows as an aligned plain-text table (values formatted with ``str``)."""
    cells = [[str(h) for h in headers]] + [[str(v) for v in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)
