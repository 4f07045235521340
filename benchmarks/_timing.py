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


# --- the machine's load: what was measured, and when it may be called other work -------------------------
BUSY_LOAD = 0.5
"""A 1-minute load average above this, on the benchmark machine's 2 cores, slows the figures measurably."""
SETTLE_LOAD_S = 180.0
"""How long :func:`settle_load` waits at most for the load average to fall under BUSY_LOAD. The 1-minute
average decays with a 60 s time constant: the residual 2.0 a previous benchmark leaves is under 0.5 after
about 85 s, so load that is still above it after this wait is other work, not a residual."""


def load_average(ndigits: int | None = None) -> float:
    """The 1-minute load average (rounded to ``ndigits`` decimals when given)."""
    value = os.getloadavg()[0]
    return value if ndigits is None else round(value, ndigits)


def wait_quiet(below: float, patience_s: float) -> float:
    """Wait (up to ``patience_s``) until the 1-minute load average is under ``below``; return it then."""
    deadline = time.monotonic() + patience_s
    while os.getloadavg()[0] >= below and time.monotonic() < deadline:
        time.sleep(5)
    return os.getloadavg()[0]


def settle_load(patience_s: float = SETTLE_LOAD_S, below: float = BUSY_LOAD) -> dict[str, Any]:
    """The load before a run: the 1-minute average now (``before``), then after waiting up to ``patience_s``
    for it to fall under ``below`` (``settled``, after ``waited_s``; None without a wait). Pass the result to
    :func:`load_note`."""
    t0 = time.monotonic()
    before = os.getloadavg()[0]
    settled = wait_quiet(below, patience_s) if patience_s > 0 else None
    return {"before": before, "settled": settled, "waited_s": round(time.monotonic() - t0, 1),
            "patience_s": patience_s}


def load_note(start: dict[str, Any] | float, end: float | None = None, *, own: str = "") -> str:
    """One sentence on the load around a measurement: the 1-minute load average ``start`` (a number, or
    :func:`settle_load`'s record) and ``end`` (which includes this run's own work, ``own`` names it).

    Other work is named only where it was measured: the load stayed above BUSY_LOAD after the settle wait. A
    high figure without the wait is reported as a number only: the 1-minute average also holds the residual
    of the work that finished before this run (a previous benchmark), which is not concurrent work."""
    rec = start if isinstance(start, dict) else {"before": float(start), "settled": None, "waited_s": 0.0}
    text = f"1-minute load average {rec['before']:.2f} at the start"
    if rec.get("settled") is not None and rec.get("waited_s", 0) >= 5:
        text += f", {rec['settled']:.2f} after waiting {rec['waited_s']:.0f} s for it to settle"
    if end is not None:
        text += f", {end:.2f} at the end" + (f" (including {own})" if own else " (including this run's own work)")
    text += f", on {os.cpu_count()} cores"
    settled = rec.get("settled")
    if settled is not None and settled > BUSY_LOAD:
        text += (f": other work was running (the load stayed above {BUSY_LOAD:g} after a {rec['waited_s']:.0f} s "
                 "wait), and timings measured alongside it are slower than on a quiet machine")
    elif settled is None and rec["before"] > BUSY_LOAD:
        text += (" (a figure above ~0.5 at the start may be the residual of work that had just finished, or other "
                 "work still running; this run did not wait to tell them apart)")
    return text + "."


# --- a served app's start-up work --------------------------------------------------------------------------
def settle_server(base: str, pid: int, cpu_seconds: Callable[[int], float], *, interval_s: float = 1.0,
                  timeout_s: float = 300.0) -> dict[str, Any]:
    """Wait until the served app at ``base`` (process ``pid``) has finished its start-up work: the kernel warm-up
    reported finished by ``/readyz``, then ``cpu_seconds(pid)`` growing by under 0.1 s over ``interval_s`` (the
    demo rig and session built, Ray's workers started). Returns the seconds that took, the kernels' state, whether
    it went quiet within ``timeout_s``, and the CPU seconds ``cpu_seconds`` counted meanwhile."""
    import httpx

    start, cpu0 = time.perf_counter(), cpu_seconds(pid)
    kernels = "unknown"
    while time.perf_counter() - start < timeout_s:
        kernels = httpx.get(f"{base}/readyz", timeout=30.0).json().get("checks", {}).get("kernels", {}).get("state")
        if kernels != "warming":
            break
        time.sleep(1.0)
    quiet = False
    while not quiet and time.perf_counter() - start < timeout_s:
        before = cpu_seconds(pid)
        time.sleep(interval_s)
        quiet = cpu_seconds(pid) - before < 0.1
    return {"seconds": time.perf_counter() - start, "kernels": kernels, "quiet": quiet,
            "server_tree_cpu_s": cpu_seconds(pid) - cpu0}
