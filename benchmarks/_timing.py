"""The one timing helper of the benchmarks: wall and thread-CPU seconds of repeated calls.

Speed figures in RESULTS.md are ratios against an anchor timed in the same run, with the load
(:func:`load`) printed beside them, because the benchmark machine is often shared.
"""
from __future__ import annotations

import os
import statistics
import time
from dataclasses import dataclass, field
from typing import Any, Callable


@dataclass
class Timing:
    """Seconds of each timed call (``wall``: perf_counter; ``cpu``: this thread's CPU time) and the
    last call's return value."""

    wall: list[float] = field(default_factory=list)
    cpu: list[float] = field(default_factory=list)
    result: Any = None

    @property
    def median(self) -> float:
        """Median wall seconds."""
        return statistics.median(self.wall)

    @property
    def best(self) -> float:
        """Fastest wall seconds (the least disturbed by other work on the machine)."""
        return min(self.wall)

    @property
    def median_cpu(self) -> float:
        """Median thread-CPU seconds."""
        return statistics.median(self.cpu)

    @property
    def median_ms(self) -> float:
        return 1000.0 * self.median


def timed(fn: Callable[[], Any], repeats: int = 1, warmup: int = 0) -> Timing:
    """Call ``fn()`` ``warmup`` times untimed (compiling, caches), then ``repeats`` times timed."""
    for _ in range(warmup):
        fn()
    out = Timing()
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.thread_time()
        out.result = fn()
        out.cpu.append(time.thread_time() - c0)
        out.wall.append(time.perf_counter() - w0)
    return out


def load() -> str:
    """The 1/5/15-minute load averages, as ``uptime`` prints them (to report beside speed figures)."""
    return ", ".join(f"{v:.2f}" for v in os.getloadavg())
