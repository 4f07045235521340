"""The local cluster's worker processes made ready at the service's start, before the first batch needs them.

A Ray worker process pays once in its life for what a batch job's task needs: the job's and the fan-out's imports
(numba, OpenCV, onnxruntime), and the orientation engine (its networks, cascades and word lists, and what its text cue
sets up at its first text photo: :mod:`workers.orientation.rehearsal`). Paid in the first
tasks, it made the first photo library after a start about a quarter slower than the next (five worker processes
started and built the engine during a 200-photo library: a batch job's own task holds a worker while its blocks run
in others; ``benchmarks/RESULTS.md``, orientation_library). At start-up the service asks each of the idle workers its
local cluster keeps (``ray_idle_workers``) to do it now (``SWEEPCAST_WARM_WORKERS``), in the background: Ray runs its
workers at low priority (nice 15), so a request that comes meanwhile is not slowed by it.

:func:`prepare_worker` is what each of those tasks runs. The tasks wait for one another (:func:`_arrive`, a barrier of
files in a folder of this machine's: the embedded cluster is one machine) so that each lands in a process of its own:
a process holding one task cannot take another.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

BARRIER_TIMEOUT_S = 120.0
"""Longest a prepared worker waits for the others (Ray starts a few processes at a time)."""
_POLL_S = 0.05


def prepare_worker(barrier: Path, count: int, timeout_s: float = BARRIER_TIMEOUT_S) -> dict[str, object]:
    """Import what a batch job's tasks import and build this process's orientation engine for the deployment's
    settings (as a batch job configures it); then wait until ``count`` processes have arrived at ``barrier`` (a folder)
    or ``timeout_s`` passed. Returns this process's id and the engine's name (None when the settings name no engine
    that can be built: the job will say why)."""
    from workers.fanout import run_task
    from workers.runtime import execute_job  # noqa: F401 - what a job's own task imports

    engine, _ = run_task(_engine_name, None)  # as a block runs: numba on the task's CPU, then the engine
    _arrive(Path(barrier), count, timeout_s)
    return {"pid": os.getpid(), "engine": engine}


def _engine_name(_: None) -> str | None:
    from workers.orientation.detect import detector_config, get_detector
    from workers.orientation.rehearsal import rehearse
    from workers.settings import worker_settings

    settings = worker_settings()
    try:
        engine = get_detector(detector_config(settings, settings.models_dir))
    except (ValueError, OSError):  # a YuNet model named but missing: the first job reports it
        return None
    rehearse(engine)  # what the first text photo would set up (its Tesseract objects), on the thread blocks run on
    return engine.name


def _arrive(barrier: Path, count: int, timeout_s: float) -> None:
    """Mark this process arrived at ``barrier`` and wait until ``count`` processes have (or ``timeout_s`` passed)."""
    (barrier / str(os.getpid())).touch()
    deadline = time.monotonic() + timeout_s
    while sum(1 for _ in barrier.iterdir()) < count and time.monotonic() < deadline:
        time.sleep(_POLL_S)
