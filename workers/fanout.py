"""Fanning a job out: one function over many tasks, here in turn or as Ray tasks on every CPU of the cluster.

A job whose work grows with its input (a photo library) splits it into tasks (blocks of photos) and calls
``ctx.fan_out(fn, tasks)``, which yields ``(index, fn(task))`` as each task finishes, in the order they finish.
``fn`` must be a module-level function and each task picklable: on Ray they travel to other processes and nodes,
where the task reads and writes through the blob store (:class:`workers.workarea.WorkArea`), never through the
queue.

- :class:`InProcess` runs the tasks one after another in this process (a job run outside Ray: tests, tools).
- :class:`OnRay` submits one Ray task per task (1 CPU each, placed wherever the cluster has a free CPU). A task whose
  worker or node is lost, or that raised, is tried again by Ray (``TASK_RETRIES``); one that failed every time
  raises its own exception here. A user's input error (:class:`~workers.common.jobctx.JobInputError`) is the same
  every time: it is raised here at once, never tried again. Where the job was routed to nodes by
  custom resources (``SWEEPCAST_JOB_RESOURCES``), its tasks go to those nodes too (spread by their CPUs; elsewhere only
  if such a node dies).
"""
from __future__ import annotations

import contextlib
import functools
import itertools
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Protocol, Sequence, TypeVar

from workers.common.jobctx import JobInputError

T = TypeVar("T")
R = TypeVar("R")

TASK_RETRIES = 3
"""How many times Ray tries a task again after its worker was lost or it raised (Ray's own default for the first)."""
WAIT_S = 1.0
"""Longest single wait for the next finished task (the caller's wait function may do other work in between)."""
_RAY_OWN = ("CPU", "GPU", "memory", "object_store_memory")

Wait = Callable[[list[Any], float], tuple[list[Any], list[Any]]]
"""``wait(refs, timeout_s) -> (ready, pending)``, as ``ray.wait(refs, num_returns=1, timeout=timeout_s)``."""


@dataclass(frozen=True)
class Refused:
    """A task's input error, handed back instead of raised so that Ray does not try the task again."""

    error: JobInputError


def run_task(fn: Callable[[T], R], task: T) -> R | Refused:
    """``fn(task)`` as a Ray task runs it: an input error comes back as :class:`Refused`."""
    try:
        return fn(task)
    except JobInputError as exc:
        return Refused(exc)


class FanOut(Protocol):
    parallelism: int
    """How many tasks can run at once (the CPUs they may use)."""

    def run(self, fn: Callable[[T], R], tasks: Sequence[T]) -> Iterator[tuple[int, R]]:
        """``(i, fn(tasks[i]))`` for every task, as each finishes."""


class InProcess:
    """Every task in this process, one after another, in order."""

    parallelism = 1

    def run(self, fn: Callable[[T], R], tasks: Sequence[T]) -> Iterator[tuple[int, R]]:
        for i, task in enumerate(tasks):
            yield i, fn(task)


class OnRay:
    """One Ray task per task, from a process that is itself a Ray task (see the module docstring).

    ``wait`` is how this process waits for the next task to finish: a Ray task releases its CPU to its
    own fan-out only while its *main* thread waits on Ray (measured with Ray 2.60: a wait in another thread keeps the
    CPU, and on two cores the tasks then ran one at a time), so a job running in a thread passes a wait that its
    main thread carries out (:mod:`workers.runtime`)."""

    def __init__(self, wait: Wait | None = None) -> None:
        import ray

        self._ray = ray
        self._wait = wait or (lambda refs, timeout: ray.wait(refs, num_returns=1, timeout=timeout))

    @functools.cached_property
    def _nodes(self) -> list[tuple[str, int]]:
        return _routed_nodes(self._ray)

    @functools.cached_property
    def parallelism(self) -> int:  # type: ignore[override]
        cpus = sum(cpu for _, cpu in self._nodes) if self._nodes else self._ray.cluster_resources().get("CPU", 1.0)
        return max(1, int(cpus))

    def run(self, fn: Callable[[T], R], tasks: Sequence[T]) -> Iterator[tuple[int, R]]:
        from workers.ray_tasks import run_block_task

        placements = _spread(self._nodes)
        pending = {}
        try:
            for i, task in enumerate(tasks):
                options = _pinned(next(placements)) if placements is not None else {}
                pending[run_block_task.options(max_retries=TASK_RETRIES, retry_exceptions=True,
                                               **options).remote(fn, task)] = i
            while pending:
                ready, _ = self._wait(list(pending), WAIT_S)
                for ref in ready:
                    yield pending.pop(ref), self._result(ref)
        finally:
            for ref in pending:  # the job stopped early (an error, a cancel): its other tasks need not run
                with contextlib.suppress(Exception):  # one that finished meanwhile
                    self._ray.cancel(ref)

    def _result(self, ref: Any) -> Any:
        try:
            value = self._ray.get(ref)
        except self._ray.exceptions.RayTaskError as exc:
            cause = exc.cause
            if isinstance(cause, Exception):  # the task's own exception, as if it had run here
                raise cause from exc
            raise
        if isinstance(value, Refused):
            raise value.error
        return value


def _routed_nodes(ray: Any) -> list[tuple[str, int]]:
    """(node id, CPUs) of each live node with CPUs that offers every custom resource this task was given; none when
    it was given none (its tasks then go wherever Ray places them)."""
    given = ray.get_runtime_context().get_assigned_resources()
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
