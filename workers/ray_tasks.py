"""Ray entry points: the batch job task (a streaming generator of job events)."""
from __future__ import annotations

from typing import Any, Iterator

import ray

from workers.runtime import JobSpec, execute_job


@ray.remote(max_retries=0)
def run_job_task(spec: dict[str, Any]) -> Iterator[dict[str, Any]]:
    """Run one attempt of a job on a Ray worker, streaming its events back to the dispatcher.

    Retries are the dispatcher's, not Ray's (``max_retries=0``): the job table counts each
    attempt, and a lost worker shows up at the driver as an error of the next item.
    """
    yield from execute_job(JobSpec(**spec))
