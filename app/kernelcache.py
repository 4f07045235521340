"""The compiled-kernel cache of the service and its workers, and its warm-up at start-up.

numba reads ``NUMBA_CACHE_DIR`` once, when it is first imported: :func:`use_cache_dir` must run before
any engine module is imported (``sweepcast serve`` and ``sweepcast worker`` call it first thing), and
the service hands the same directory to its Ray workers (``app.raycluster.worker_env``). The warm-up
(:mod:`workers.warmup`) runs in its own low-priority process, so that it neither holds the API's
event loop nor takes the CPU from a request; a request that needs a kernel before it is warm
compiles it itself, as it would without the warm-up.
"""
from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

log = logging.getLogger("sweepcast.kernels")

WARMUP_NICENESS = 19
"""The warm-up's priority: the lowest. Ray runs its workers (jobs, the viewers' session actors) at nice 15,
so anything less than that would take the CPU from the very requests the warm-up is there to speed up."""


def use_cache_dir(path: Path) -> Path:
    """Make ``path`` this process's (and its children's) numba cache; created when missing."""
    path.mkdir(parents=True, exist_ok=True)
    os.environ["NUMBA_CACHE_DIR"] = str(path)
    return path


@dataclass
class KernelWarmup:
    """The background warm-up process of one service start (``state``: off, warming, done, failed)."""

    proc: subprocess.Popen | None = None
    started: float = field(default_factory=time.monotonic)
    seconds: dict[str, float] | None = None
    error: str | None = None
    current: bool = False  # the cache was already warm for this code and CPU: nothing started

    @classmethod
    def start(cls, cache_dir: Path, report: bool = True, engines: tuple[str, ...] = ()) -> "KernelWarmup":
        """Start ``python -m workers.warmup [engines]`` (default: all) with ``cache_dir`` as its numba cache,
        at lower priority; ``report``: read its result for :meth:`status` (else its output is discarded). Nothing
        to start when a warm-up of every engine stamped the cache for this very code and CPU
        (:func:`workers.warmup.is_current`): it would only load every kernel, seconds of CPU at every start."""
        from workers.warmup import is_current

        if not engines and is_current(cache_dir):
            log.info("the kernels in %s are current for this code and CPU: no warm-up", cache_dir)
            return cls(current=True)
        env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir)}
        out = subprocess.PIPE if report else subprocess.DEVNULL
        # its own process group: it compiles in one process per core, and stop() ends them all
        proc = subprocess.Popen([sys.executable, "-m", "workers.warmup", *engines], env=env, stdout=out,
                                stdin=subprocess.DEVNULL, preexec_fn=lambda: os.nice(WARMUP_NICENESS),
                                start_new_session=True)
        log.info("compiling the engines' kernels in the background (pid %d) into %s", proc.pid, cache_dir)
        return cls(proc)

    @property
    def state(self) -> str:
        if self.proc is None:
            return "done" if self.current else "off"
        if self.proc.poll() is None:
            return "warming"
        if self.seconds is None and self.error is None:
            self._collect()
        return "done" if self.error is None else "failed"

    def _collect(self) -> None:
        out = self.proc.stdout.read() if self.proc.stdout is not None else b""
        try:
            self.seconds = json.loads(out.decode().strip().splitlines()[-1]) if self.proc.returncode == 0 else None
        except (ValueError, IndexError):
            self.seconds = None
        if self.seconds is None:
            self.error = f"the warm-up exited with code {self.proc.returncode}"

    def status(self) -> dict[str, object]:
        """For ``/readyz``: never a reason to be unready (a cold kernel is only slower the first time)."""
        state = self.state
        report: dict[str, object] = {"ok": True, "state": state}
        if state == "warming":
            report["detail"] = f"compiling for {time.monotonic() - self.started:.0f} s"
        elif state == "done" and self.current:
            report["detail"] = "the cache is current for this code and CPU (stamped by the last full warm-up)"
        elif state == "done":
            report["seconds"] = self.seconds
        elif state == "failed":
            report["detail"] = self.error
        return report

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            _signal_group(self.proc, signal.SIGTERM)
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                _signal_group(self.proc, signal.SIGKILL)


def _signal_group(proc: subprocess.Popen, sig: int) -> None:
    try:
        os.killpg(proc.pid, sig)
    except ProcessLookupError:
        pass
