"""Connecting to Ray: a local cluster by default, an existing one when an address is set."""
from __future__ import annotations

import asyncio
import logging
import os
import shutil
import sys
import tempfile
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

from app.netwait import wait_for_gcs
from app.raystart import start_node
from app.settings import Settings
from workers.common.cores import usable_cores
from workers.common.models import models_dir
from workers.settings import WorkerSettings

log = logging.getLogger("sweepcast.ray")


def connect(address: str | None, num_cpus: int | None = None, env: dict[str, str] | None = None,
            idle_workers: int | None = None) -> bool:
    """Initialise Ray in this process; return True when this call started it (and so owns it).

    The embedded default starts a local cluster on loopback without the dashboard, with Ray's
    token authentication off (it listens on loopback only). A real cluster keeps its own
    security settings: see the README's scale-out section for the token. ``env`` is set on
    every worker process that runs this service's tasks. ``idle_workers``: the worker processes
    a local cluster keeps alive when idle (:func:`idle_worker_limit`); a real cluster's are its own.
    """
    import ray

    if ray.is_initialized():
        return False
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    kwargs: dict[str, Any] = {"ignore_reinit_error": True, "log_to_driver": True}
    if env:
        kwargs["runtime_env"] = {"env_vars": dict(env)}
    if address:
        ray.init(address=address, **kwargs)
    else:
        os.environ.setdefault("RAY_AUTH_MODE", "disabled")
        temp_dir = os.path.join(tempfile.gettempdir(), "sweepcast-ray")
        ray.init(num_cpus=num_cpus, include_dashboard=False, _temp_dir=temp_dir,
                 _system_config={"num_workers_soft_limit": idle_worker_limit(num_cpus, idle_workers)}, **kwargs)
    log.info("Ray ready: %s", ray.cluster_resources())
    return True


async def prepare_workers(count: int, timeout_s: float = 300.0) -> list[dict[str, Any]]:
    """Make ``count`` of the local cluster's worker processes ready for batch jobs (:mod:`workers.prewarm`), each in a
    task of its own; what each said. The tasks are awaited on the event loop (at most ``timeout_s``): a service
    stopped meanwhile leaves no thread waiting on Ray."""
    from workers.ray_tasks import prepare_worker_task

    with tempfile.TemporaryDirectory(prefix="sweepcast-prewarm-") as barrier:
        refs = [prepare_worker_task.remote(barrier, count) for _ in range(count)]
        async with asyncio.timeout(timeout_s):
            return [await ref for ref in refs]


def idle_worker_limit(num_cpus: int | None, setting: int | None = None) -> int:
    """The worker processes a local cluster of ``num_cpus`` (None: the cores this process may use) keeps when idle:
    ``setting``, else twice the CPUs and two more, at most the CPUs + 8. Ray's own default, one per CPU, ends the
    workers a batch job's blocks ran in as soon as they idle (a second), since the job's own task holds a worker while
    it waits: each library then paid their start again (Python, the engine's imports, its detectors: 2-3 s of CPU
    each). The two more: with every worker busy (two batches' own tasks and their blocks, on two cores), Ray starts a
    process for a block waiting behind them (:data:`workers.fanout.IN_FLIGHT_PER_CPU`); with two idle ones ready
    (and made ready at the start: ``SWEEPCAST_WARM_WORKERS``), the first library after a start on two cores started
    none where it had started two (three first libraries each way, one after the other, 2026-12-08: 12.3-14.4 photos/s,
    median 14.3, against 11.5-13.3, median 13.0). Each idle worker that has analysed photos holds 0.25-0.7 GB."""
    if setting is not None:
        return setting
    cpus = num_cpus or usable_cores()
    return min(2 * cpus + 2, cpus + 8)


_early: tuple[Settings, Future[bool]] | None = None
# Ray's client breaks (later calls hang) when the thread that ran ray.init ends: the early start's
# thread is an executor's, which lives as long as the process.
_connector = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ray-connect")


JOIN_FAILED_EXIT_CODE = 3
"""The exit code of a service whose join as a node failed (``ray_join_node``): its supervisor starts it again."""


def start_connecting(settings: Settings) -> None:
    """Begin :func:`connect_for` on a thread now, so that Ray's start (seconds of waiting for its
    processes) overlaps the service's own imports; the lifespan's :func:`connect_for` then waits for it. With
    ``ray_join_node``, this machine's node joins the cluster first, on that thread too."""
    global _early
    join = bool(settings.ray_join_node and settings.ray_address)
    _early = (settings, _connector.submit(_connect_as, settings, join))


def ray_executable() -> str | None:
    """The ``ray`` command of this environment (beside this Python), else the first on PATH."""
    return shutil.which("ray", path=os.path.dirname(sys.executable)) or shutil.which("ray")


HEAD_WAIT_S = 300.0
"""How long a node waits for its head's port before ``ray start`` tries anyway (and says what is wrong)."""


def join_as_node(address: str) -> int:
    """``ray start --address ADDRESS --num-cpus=0``: this machine joins the cluster as a node that runs no tasks (the
    local raylet a driver connects through), once the head's GCS answers (:mod:`app.netwait`), started again if it
    stalls reaching it (:mod:`app.raystart`). Its exit code."""
    ray_bin = ray_executable() or "ray"
    wait_for_gcs(address, HEAD_WAIT_S, ray_bin)
    log.info("joining the Ray cluster at %s as a node without CPUs", address)
    return start_node([ray_bin, "start", f"--address={address}", "--num-cpus=0", "--disable-usage-stats"])


def connect_for(settings: Settings) -> bool:
    """:func:`connect` as ``settings`` say, with :func:`worker_env` for the workers (the result of
    :func:`start_connecting` when it was called for these settings). Blocking."""
    if _early is not None and _early[0] is settings:
        return _early[1].result()
    return _connect_as(settings)


def forget_connect_attempt() -> None:
    """After a failed :func:`connect_for`: the next one tries again (not the early start's failure), and Ray's
    half-made state of the failed ``ray.init`` is cleared."""
    global _early
    _early = None
    try:
        import ray

        if ray.is_initialized():
            ray.shutdown()
    except Exception:  # noqa: BLE001 - nothing to clear
        pass


def _connect_as(settings: Settings, join: bool = False) -> bool:
    if join and (code := join_as_node(settings.ray_address)) != 0:  # no node of ours: ray.init would wait in vain
        log.error("could not join the Ray cluster at %s (ray start exited with code %d): exiting (code %d) to be "
                  "started again", settings.ray_address, code, JOIN_FAILED_EXIT_CODE)
        logging.shutdown()
        os._exit(JOIN_FAILED_EXIT_CODE)
    return connect(settings.ray_address, settings.ray_num_cpus, worker_env(settings), settings.ray_idle_workers)


def worker_env(settings: Settings) -> dict[str, str]:
    """Settings the engines read on the workers, passed to every Ray worker of this service."""
    values = settings.model_dump(include=set(WorkerSettings.model_fields))
    values["models_dir"] = models_dir(settings.data_dir)  # models fetched later are found too
    values["demo_cache_dir"] = settings.resolved_demo_cache_dir
    env = {f"SWEEPCAST_{name.upper()}": _env_value(value) for name, value in values.items() if value is not None}
    # OpenCV's own guard, read once when a fresh worker imports cv2: a second line behind the header check
    env["OPENCV_IO_MAX_IMAGE_PIXELS"] = str(settings.max_image_pixels)
    env["NUMBA_CACHE_DIR"] = str(settings.resolved_numba_cache_dir)  # the kernels the warm-up compiled
    # Each job runs in a thread of its own, and glibc gives threads arenas of their own (up to 8 per core): a Ray
    # worker's memory then wandered 445-566 MB over 140 jobs of the soak's mix and drifted up; with two arenas it
    # stayed within 416-434 MB, at the same speed, and benchmarks/soak.py's hour found it flat (issue 35's closing
    # note). An operator's own MALLOC_ARENA_MAX wins.
    env["MALLOC_ARENA_MAX"] = os.environ.get("MALLOC_ARENA_MAX", "2")
    return env


def _env_value(value: object) -> str:
    """A setting as its environment variable spells it (paths absolute: workers run elsewhere)."""
    if isinstance(value, bool):
        return "1" if value else "0"
    return str(value.resolve()) if isinstance(value, Path) else str(value)


def ready() -> tuple[bool, str]:
    """Whether Ray answers, and a short reason."""
    try:
        import ray

        if not ray.is_initialized():
            return False, "Ray is not connected yet"
        return describe_nodes(ray.nodes())
    except Exception as exc:  # noqa: BLE001 - readiness reports, it never raises
        return False, f"Ray unreachable: {type(exc).__name__}: {exc}"


def describe_nodes(nodes: list[dict]) -> tuple[bool, str]:
    """Readiness from ``ray.nodes()``: ready with a live node. A cluster whose live nodes offer no CPU (its workers
    gone) is still ready, since uploads are accepted and jobs wait for a worker (failing after
    ``SWEEPCAST_JOB_UNSCHEDULABLE_SECONDS``), but says so: an operator's probe then shows why nothing runs."""
    live = [n for n in nodes if n.get("Alive")]
    if not live:
        return False, "no live Ray node"
    cpus = sum(float((n.get("Resources") or {}).get("CPU", 0)) for n in live)
    if cpus <= 0:
        return True, f"{len(live)} Ray node(s), none with CPUs: jobs wait until a worker joins"
    return True, f"{len(live)} Ray node(s), {cpus:g} CPU(s) for jobs"
