"""The compiled-kernel cache of the service and its workers, and its warm-up at start-up.

numba reads ``NUMBA_CACHE_DIR`` once, when it is first imported: :func:`use_cache_dir` must run before
any engine module is imported (``sweepcast serve`` and ``sweepcast worker`` call it first thing), and
the service hands the same directory to its Ray workers (``app.raycluster.worker_env``). The warm-up
(:mod:`workers.warmup`) runs in its own low-priority process, so that it neither holds the API's
event loop nor takes the CPU from a request; a request that needs a kernel before it is warm
compiles it itself, as it would without the warm-up.

Kernels compiled ahead (``SWEEPCAST_PREBUILT_KERNELS``: the Docker image's, compiled at build for a portable CPU
target) make both unnecessary: :func:`use_prebuilt` copies them into the cache and sets numba's CPU target to
theirs, before numba is imported, on every CPU that runs that target.
"""
from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from workers.common.spawn import niced

log = logging.getLogger("sweepcast.kernels")

WARMUP_NICENESS = 19
"""The warm-up's priority: the lowest. Ray runs its workers (jobs, the viewers' session actors) at nice 15,
so anything less than that would take the CPU from the very requests the warm-up is there to speed up."""


PREBUILT_STATE: dict[str, str] = {}
"""What :func:`use_prebuilt` decided in this process (``state``: used / not used, ``detail``), for ``/readyz``."""


def use_prebuilt(prebuilt: Path | None, cache_dir: Path) -> dict[str, str]:
    """Use the kernels compiled ahead in ``prebuilt`` (a cache stamped by ``sweepcast warmup --target T``): when this
    CPU runs the target T and the stamp matches this code, numba and Python, set numba's CPU target to T for this
    process and its children (Ray's local workers; must run before numba is imported) and copy the kernels into
    ``cache_dir`` where missing (``prebuilt`` may be read-only: numba writes only into ``cache_dir``). Otherwise leave
    numba on this CPU and say why: its kernels compile into ``cache_dir`` (the background warm-up). Returned as
    ``{"state": "used" | "not used", "detail": ...}`` (also kept in :data:`PREBUILT_STATE`)."""
    from workers.portable_cache import TARGETS, host_supports, target_env, target_features
    from workers.warmup import STAMP_NAME, fingerprint, read_stamp

    PREBUILT_STATE.clear()
    if prebuilt is None:
        return PREBUILT_STATE
    stamp = read_stamp(prebuilt) or {}
    target = stamp.get("cpu_name")
    missing = host_supports(target) if target in TARGETS else []
    if target not in TARGETS or stamp.get("cpu_features") != target_features(target):
        why = f"{prebuilt} holds no kernels stamped for a portable CPU target (`sweepcast warmup --target`)"
    elif missing:
        why = f"this CPU lacks {', '.join(missing)} of the {target} target the kernels in {prebuilt} were built for"
    elif stamp.get("fingerprint") != fingerprint((target, target_features(target))):
        why = f"the kernels in {prebuilt} were built for other sources, numba or Python"
    elif "numba" in sys.modules:
        why = "numba was imported before the CPU target could be set"
    else:
        os.environ.update(target_env(target))
        copied = _copy_missing(prebuilt, cache_dir, last=STAMP_NAME)
        PREBUILT_STATE.update(state="used", detail=f"kernels compiled ahead for {target} in {prebuilt} "
                                                   f"({copied} files copied into {cache_dir})")
        return PREBUILT_STATE
    PREBUILT_STATE.update(state="not used", detail=f"{why}: compiling for this CPU into {cache_dir}")
    return PREBUILT_STATE


def log_prebuilt() -> None:
    """Log what :func:`use_prebuilt` decided (it runs before the service's log has a handler)."""
    if PREBUILT_STATE.get("state") == "used":
        log.info("using the %s", PREBUILT_STATE["detail"])
    elif PREBUILT_STATE:
        log.warning("not using the prebuilt kernels: %s", PREBUILT_STATE["detail"])


def _copy_missing(src: Path, dst: Path, last: str) -> int:
    """Copy every file of ``src`` that ``dst`` lacks (or holds at another size), each atomically, ``last`` (the
    stamp) after all the others; the number copied."""
    files = sorted((p for p in src.rglob("*") if p.is_file()), key=lambda p: p.name == last)
    copied = 0
    for path in files:
        target = dst / path.relative_to(src)
        if target.exists() and target.stat().st_size == path.stat().st_size and path.name != last:
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        part = target.with_name(f"{target.name}.{os.getpid()}.part")
        shutil.copyfile(path, part)
        os.replace(part, target)
        copied += 1
    return copied


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
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _stopped: bool = False

    @classmethod
    def start(cls, cache_dir: Path, report: bool = True, engines: tuple[str, ...] = ()) -> "KernelWarmup":
        """Start ``python -m workers.warmup [engines]`` (default: all) with ``cache_dir`` as its numba cache,
        at lower priority; ``report``: read its result for :meth:`status` (else its output is discarded). Nothing
        to start when a warm-up of every engine stamped the cache for this very code and CPU
        (:func:`workers.warmup.is_current`): it would only load every kernel, seconds of CPU at every start."""
        from workers.warmup import ENGINES, is_current

        if not engines and is_current(cache_dir):
            log.info("the kernels in %s are current for this code and CPU: no warm-up", cache_dir)
            return cls(current=True)
        env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir)}
        out = subprocess.PIPE if report else subprocess.DEVNULL
        # its own process group: it compiles in one process per core, and stop() ends them all
        proc = subprocess.Popen(niced([sys.executable, "-m", "workers.warmup", *engines], WARMUP_NICENESS), env=env,
                                stdout=out, stdin=subprocess.DEVNULL, start_new_session=True)
        log.info("compiling the kernels of %s in the background (pid %d; each engine logs when it is done) into %s",
                 ", ".join(engines or ENGINES), proc.pid, cache_dir)
        warmup = cls(proc)
        if report:  # the log says when it is over, and how long each engine took
            threading.Thread(target=warmup._log_when_done, name="kernel-warmup", daemon=True).start()
        return warmup

    def _log_when_done(self) -> None:
        self.proc.wait()
        state = self.state
        if state == "done":
            log.info("kernels compiled in %.0f s: %s", time.monotonic() - self.started,
                     ", ".join(f"{k} {v:.1f} s" for k, v in (self.seconds or {}).items()))
        elif state == "failed" and not self._stopped:
            log.warning("the kernel warm-up failed (%s): requests compile what they need", self.error)

    @property
    def state(self) -> str:
        if self.proc is None:
            return "done" if self.current else "off"
        if self.proc.poll() is None:
            return "warming"
        with self._lock:
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
        if PREBUILT_STATE:
            report["prebuilt"] = dict(PREBUILT_STATE)
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
        self._stopped = True
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
