"""Fanning a job out: one function over many items, here in turn or as Ray tasks on every CPU of the cluster.

A job whose work grows with its input (a photo library, a drone survey of hundreds of stills) splits it into small,
picklable items (blocks of photos, keys, indices: the bulk goes through the job's
:class:`~workers.workarea.WorkArea`) and runs a module-level function over them with its context's fan-out
(``ctx.fanout()``):

- ``fan.run(fn, items, stage)`` yields ``(i, fn(items[i]))`` as each item finishes, in the order they finish;
- ``fan.map(stage, fn, items, on_done)`` returns ``[fn(item) for item in items]`` and calls ``on_done(i, result)``
  as item i finishes (progress, and what the stage collects).

Every run is recorded under its stage (:class:`TaskRun`: the node it ran on, its wall and CPU seconds, its process's
peak resident memory) for the job's report (:func:`stage_summary`: tasks per node).

- :class:`InProcess` runs the items one after another in this process (a job run outside Ray: the command line,
  tests); each may use every core through its own kernels.
- :class:`OnRay` submits one Ray task of one CPU per item, spread over the nodes (``SPREAD``), whose numba kernels
  use that one CPU (one task per core, not one task taking them all). A task whose worker or node is lost, or that
  raised, is tried again by Ray (``TASK_RETRIES``; its output is written atomically, so a second run replaces the
  first). A user's input error (:class:`~workers.common.jobctx.JobInputError`) is the same every time: it is raised
  here at once, never tried again; the store's own condition (full, unavailable) as itself, for the runtime to wait
  out; any other error that survived the retries as :class:`FanoutError` naming the stage. Where the job was routed
  to nodes by custom resources (``SWEEPCAST_JOB_RESOURCES``), its tasks go to those nodes too (spread by their
  CPUs; elsewhere only if such a node dies).
"""
from __future__ import annotations

import contextlib
import functools
import itertools
import resource
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Sequence, TypeVar

from workers.common.jobctx import JobInputError
from workers.storage import storage_full, storage_unavailable

T = TypeVar("T")
R = TypeVar("R")

TASK_RETRIES = 3
"""How many times Ray tries a task again after its worker was lost or it raised (Ray's own default for the first)."""
WAIT_S = 1.0
"""Longest single wait for the next finished task (the caller's wait function may do other work in between)."""
IN_FLIGHT_PER_CPU = 1
"""Tasks a fan-out keeps submitted per CPU they may use; the next is submitted as one finishes (a task waiting for a
CPU is still ready when one frees: two jobs at once keep two per CPU). Not all at once: Ray 2.60's raylet counts an
owner's tasks beyond the lease it is asking for as a backlog, and starts a worker process for each when it has no
idle one, whatever ``enable_worker_prestart`` says (its debug log: "Prestarting 3 workers given lease backlog size 3
and available CPUs 4 num idle workers 0"). Such a process imports Ray and, here, never ran a task: 0.75 s of CPU each.
With every block of a batch submitted at once, a 200-photo library on two cores (batches of 50, two at once) started
three or four during the first library after the service's start and one or two during each later one; with one task
per CPU, two or three during the first and none after; with two idle workers more as well, none
(:func:`app.raycluster.idle_worker_limit`)."""
_RAY_OWN = ("CPU", "GPU", "memory", "object_store_memory")

Wait = Callable[[list[Any], float], tuple[list[Any], list[Any]]]
"""``wait(refs, timeout_s) -> (ready, pending)``, as ``ray.wait(refs, num_returns=1, timeout=timeout_s)``."""


@dataclass(frozen=True)
class TaskRun:
    """One item's run: the ``node`` (Ray's node id, or ``local``), wall and CPU seconds, and the peak resident
    memory (MB) of the process that ran it, so far."""

    node: str
    seconds: float
    cpu_seconds: float
    peak_rss_mb: float


@dataclass(frozen=True)
class Refused:
    """A task's input error, handed back instead of raised so that Ray does not try the task again."""

    error: JobInputError


class FanoutError(RuntimeError):
    """A stage's task failed, every time, with an error that is not the user's input."""


def _peak_rss_mb() -> float:
    # Linux reports ru_maxrss in kilobytes.
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _node() -> str:
    try:
        import ray

        if ray.is_initialized():
            return ray.get_runtime_context().get_node_id()
    except Exception:  # noqa: BLE001 - outside Ray there is no node id
        pass
    return "local"


def run_item(fn: Callable[[T], R], item: T) -> tuple[R, TaskRun]:
    """``fn(item)`` and its :class:`TaskRun` (in whichever process runs it)."""
    t0, c0 = time.perf_counter(), time.process_time()
    result = fn(item)
    return result, TaskRun(_node(), time.perf_counter() - t0, time.process_time() - c0, _peak_rss_mb())


def _one_cpu_kernels() -> None:
    """numba's parallel kernels on the task's own CPUs: Ray gives a task one, and a node runs one task per core. A
    failed import of numba is raised, not passed over: the task's error should say why it could not run."""
    import numba

    try:
        import ray

        cpus = ray.get_runtime_context().get_assigned_resources().get("CPU", 1.0)
        numba.set_num_threads(max(1, min(int(cpus), numba.config.NUMBA_NUM_THREADS)))
    except Exception:  # noqa: BLE001 - the kernels then keep numba's default
        pass


def run_task(fn: Callable[[T], R], item: T) -> tuple[R | Refused, TaskRun | None]:
    """``fn(item)`` as a Ray task runs it (:func:`workers.ray_tasks.run_block_task`): kernels on the task's CPU, the
    run recorded, an input error handed back as :class:`Refused`."""
    _one_cpu_kernels()
    try:
        return run_item(fn, item)
    except JobInputError as exc:
        return Refused(exc), None


def tasks_per_node(runs: Sequence[TaskRun]) -> dict[str, int]:
    """How many runs each node did."""
    return dict(Counter(r.node for r in runs))


def stage_summary(runs: Sequence[TaskRun]) -> dict[str, Any]:
    """JSON-able figures of a stage's runs: tasks per node, the summed wall and CPU seconds, the largest peak
    resident memory of a process that ran one (MB)."""
    return {"tasks": len(runs), "tasks_per_node": tasks_per_node(runs),
            "task_seconds": round(sum(r.seconds for r in runs), 3),
            "task_cpu_seconds": round(sum(r.cpu_seconds for r in runs), 3),
            "peak_rss_mb": round(max((r.peak_rss_mb for r in runs), default=0.0), 1)}


@dataclass
class FanOut:
    """What a job's context hands out (:class:`InProcess` or :class:`OnRay`): the runs recorded per stage, and
    :meth:`map` over :meth:`run`."""

    runs: dict[str, list[TaskRun]] = field(default_factory=dict)
    parallelism: int = 1
    """How many items can run at once (the CPUs they may use)."""

    def run(self, fn: Callable[[T], R], items: Sequence[T], stage: str = "tasks") -> Iterator[tuple[int, R]]:
        """``(i, fn(items[i]))`` for every item, as each finishes."""
        raise NotImplementedError

    def map(self, stage: str, fn: Callable[[T], R], items: Sequence[T],
            on_done: Callable[[int, R], None] | None = None) -> list[R]:
        """``[fn(item) for item in items]``, in any order of execution; ``on_done(i, result)`` as item i ends."""
        out: list[Any] = [None] * len(items)
        for i, result in self.run(fn, items, stage):
            out[i] = result
            if on_done is not None:
                on_done(i, result)
        return out

    def _record(self, stage: str, run: TaskRun | None) -> None:
        if run is not None:
            self.runs.setdefault(stage, []).append(run)


@dataclass
class InProcess(FanOut):
    """Every item in this process, one after another, in order."""

    def run(self, fn: Callable[[T], R], items: Sequence[T], stage: str = "tasks") -> Iterator[tuple[int, R]]:
        for i, item in enumerate(items):
            result, run = run_item(fn, item)
            self._record(stage, run)
            yield i, result


class OnRay(FanOut):
    """One Ray task per item, from a process that is itself a Ray task (see the module docstring).

    ``wait`` is how this process waits for the next task to finish: a Ray task releases its CPU to its own fan-out
    only while its *main* thread waits on Ray (measured with Ray 2.60: a wait in another thread keeps the CPU, and on
    two cores the tasks then ran one at a time), so a job running in a thread passes a wait that its main thread
    carries out (:mod:`workers.runtime`)."""

    def __init__(self, wait: Wait | None = None) -> None:
        import ray

        self.runs = {}  # not the dataclass's __init__: it would set parallelism, which this class works out
        self._ray = ray
        self._wait = wait or (lambda refs, timeout: ray.wait(refs, num_returns=1, timeout=timeout))

    @functools.cached_property
    def _nodes(self) -> list[tuple[str, int]]:
        return _routed_nodes(self._ray)

    @property
    def in_flight(self) -> int:
        """How many tasks are submitted at once: ``IN_FLIGHT_PER_CPU`` per CPU the tasks may use (see there)."""
        return IN_FLIGHT_PER_CPU * self.parallelism

    @functools.cached_property
    def parallelism(self) -> int:  # type: ignore[override]
        """How many items can run at once (the CPUs of the nodes the tasks may go to)."""
        cpus = sum(cpu for _, cpu in self._nodes) if self._nodes else self._ray.cluster_resources().get("CPU", 1.0)
        return max(1, int(cpus))

    def run(self, fn: Callable[[T], R], items: Sequence[T], stage: str = "tasks") -> Iterator[tuple[int, R]]:
        from workers.ray_tasks import run_block_task

        placements = _spread(self._nodes)
        pending: dict[Any, tuple[int, str | None]] = {}  # ref -> (item, the node it was pinned to)
        queued = iter(enumerate(items))

        def submit(node: str | None = None) -> None:
            """The next item, if any: pinned to ``node``, else to the next node in turn (or spread by Ray)."""
            if (queued_item := next(queued, None)) is None:
                return
            i, item = queued_item
            if node is None and placements is not None:
                node = next(placements)
            where = _pinned(node) if node is not None else {"scheduling_strategy": "SPREAD"}
            pending[run_block_task.options(max_retries=TASK_RETRIES, retry_exceptions=True,
                                           name=f"sweepcast {stage}", **where).remote(fn, item)] = (i, node)

        try:
            for _ in range(self.in_flight):
                submit()
            while pending:
                ready, _ = self._wait(list(pending), WAIT_S)
                for ref in ready:
                    i, node = pending.pop(ref)
                    submit(node)  # to the CPU that just freed, before this result is read
                    yield i, self._result(stage, ref)
        finally:
            # The job stopped early (an error, a cancel): its other tasks need not run. Forced: Ray's plain cancel
            # raises KeyboardInterrupt wherever the task is, an import included, and the worker it leaves behind
            # runs later tasks with that module half-imported (numba without its ``core``: every kernel fails).
            for ref in pending:
                with contextlib.suppress(Exception):  # one that finished meanwhile
                    self._ray.cancel(ref, force=True)

    def _result(self, stage: str, ref: Any) -> Any:
        try:
            value, run = self._ray.get(ref)
        except self._ray.exceptions.RayTaskError as exc:
            cause = exc.cause if isinstance(exc.cause, Exception) else exc
            if storage_full(cause) or storage_unavailable(cause):  # the store's condition: the job waits it out
                raise cause from exc
            raise FanoutError(f"stage {stage!r}: {type(cause).__name__}: {cause}") from cause
        if isinstance(value, Refused):
            raise value.error
        self._record(stage, run)
        return value


def _routed_nodes(ray: Any) -> list[tuple[str, int]]:
    """(node id, CPUs) of each live node with CPUs that offers every custom resource this task was given; none when
    it was given none (its tasks then go wherever Ray spreads them)."""
    try:
        given = ray.get_runtime_context().get_assigned_resources()
    except AssertionError:  # Ray's answer in a driver (a test, a tool): nothing assigned, nothing routed
        return []
    custom = [k for k in given if k not in _RAY_OWN and ":" not in k]
    if not custom:
        return []
    return [(node["NodeID"], int(node["Resources"].get("CPU", 0))) for node in ray.nodes()
            if node.get("Alive") and node["Resources"].get("CPU", 0) >= 1
            and all(k in node["Resources"] for k in custom)]


def _spread(nodes: list[tuple[str, int]]) -> Iterator[str] | None:
    """Node ids in turn, each as often as it has CPUs (A with 3, B with 1: A B A A ...); None without nodes."""
    if not nodes:
        return None
    turns = sorted((k, index) for index, (_, cpus) in enumerate(nodes) for k in range(cpus))
    return itertools.cycle([nodes[index][0] for _, index in turns])


def _pinned(node_id: str) -> dict[str, Any]:
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    return {"scheduling_strategy": NodeAffinitySchedulingStrategy(node_id, soft=True)}
