"""Ray entry points: the batch job task (a streaming generator of job events), the task a job fans out into (one
block of its work: :mod:`workers.fanout`), the probe that asks a node how many processes the kernel's OOM killer
has ended there, and the start-up task that makes a worker ready (:mod:`workers.prewarm`)."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Iterator

import ray

from workers.fanout import run_task
from workers.oom import oom_kills
from workers.prewarm import prepare_worker
from workers.runtime import JobSpec, execute_job


@ray.remote(max_retries=0)
def run_job_task(spec: dict[str, Any]) -> Iterator[dict[str, Any]]:
    """Run one attempt of a job on a Ray worker, streaming its events back to the dispatcher.

    Retries are the dispatcher's, not Ray's (``max_retries=0``): the job table counts each
    attempt, and a lost worker shows up at the driver as an error of the next item.
    """
    yield from execute_job(JobSpec(**spec), on_ray=True)


@ray.remote(num_cpus=1)
def run_block_task(fn: Callable[[Any], Any], task: Any) -> Any:
    """``fn(task)``: one task of a job that fans out (:func:`workers.fanout.run_task`; retries:
    :data:`workers.fanout.TASK_RETRIES`, set where it is submitted)."""
    return run_task(fn, task)


@ray.remote(num_cpus=0, max_retries=0)
def node_oom_kills() -> int | None:
    """:func:`workers.oom.oom_kills` on the node this runs on (the dispatcher pins it to the node of a lost attempt)."""
    return oom_kills()


@ray.remote(num_cpus=0, max_retries=0)
def prepare_worker_task(barrier: str, count: int) -> dict[str, Any]:
    """:func:`workers.prewarm.prepare_worker` in one of the local cluster's workers (the service's start-up)."""
    return prepare_worker(Path(barrier), count)
