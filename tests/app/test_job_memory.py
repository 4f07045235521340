"""A job that runs its node out of memory: it fails with a reason that says so, and the job Ray stopped beside it
goes on (its retry, like every retry after running out of memory, runs alone on a node)."""
from __future__ import annotations

import os

import pytest
import ray
import ray.exceptions

import workers.ray_tasks
from harness.photos import FACES_ONLY, batch_files
from tests.app.test_jobs_e2e import wait_final
from harness.servers import ROOT


class MemoryMonitor:
    """``run_job_task`` as Ray runs it, except that an attempt chosen by ``stops(spec)`` ends as it does when Ray's
    memory monitor kills its worker: the caller gets OutOfMemoryError. Records each attempt's options."""

    def __init__(self, real, stops) -> None:
        self.real, self.stops, self.attempts = real, stops, []

    def options(self, **options):
        monitor = self

        class Submit:
            @staticmethod
            def remote(spec):
                stopped = monitor.stops(spec)
                monitor.attempts.append((len(spec["inputs"]), spec["attempt"], options, stopped))
                return Stopped() if stopped else monitor.real.options(**options).remote(spec)

        return Submit


class Stopped:
    def __aiter__(self):
        return self

    async def __anext__(self):
        raise ray.exceptions.OutOfMemoryError("Task was killed due to the node running low on memory.")


def test_a_job_that_runs_out_of_memory_fails_saying_so_and_its_neighbour_goes_on_alone(client_factory, monkeypatch):
    # the 3-photo batch runs out of memory every time; the 2-photo batch was stopped beside it once
    monitor = MemoryMonitor(workers.ray_tasks.run_job_task,
                            lambda spec: len(spec["inputs"]) == 3 or (len(spec["inputs"]) == 2 and spec["attempt"] == 1))
    monkeypatch.setattr(workers.ray_tasks, "run_job_task", monitor)
    client = client_factory(job_max_attempts=3)
    oversized = client.post("/v1/photos/batches", files=batch_files(3), data=FACES_ONLY).json()["id"]
    neighbour = client.post("/v1/photos/batches", files=batch_files(2), data=FACES_ONLY).json()["id"]

    failed = wait_final(client, oversized)
    assert failed["state"] == "failed" and failed["error"].startswith("the job ran out of memory"), failed
    assert "stopped 3 times (by Ray's memory monitor or the kernel's OOM killer; of 3 times lost, the attempts after that " \
           "alone on a node)" in failed["error"]
    done = wait_final(client, neighbour)
    assert done["state"] == "succeeded" and done["attempts"] == 2, done
    assert len(client.get(f"/v1/jobs/{neighbour}/results/report.json").json()) == 2

    node_cpus = max(n["Resources"].get("CPU", 0) for n in ray.nodes() if n["Alive"])
    assert node_cpus > 1
    for inputs, attempt, options, _ in monitor.attempts:  # the first attempt as the kind asks; later ones alone
        assert options["num_cpus"] == (1 if attempt == 1 else node_cpus), monitor.attempts
    assert sorted((i, a) for i, a, _, _ in monitor.attempts) == [(2, 1), (2, 2), (3, 1), (3, 2), (3, 3)]


NODE = "ab" * 28  # a node id as Ray writes one


async def _value(value):
    return value


class KilledByTheKernel:
    """An attempt that starts (its ``started`` event carries its node's OOM-kill count, ``kills``) and then loses its
    worker without a word from Ray, as when the kernel's OOM killer ends it at a container's memory limit."""

    def __init__(self, spec, kills: int) -> None:
        self.started = {"type": "started", "attempt": spec["attempt"], "node_id": NODE, "pid": 1, "oom_kills": kills}

    def __aiter__(self):
        return self

    async def __anext__(self):
        if self.started is not None:
            event, self.started = self.started, None
            return _value(event)
        raise ray.exceptions.WorkerCrashedError()


class NodeProbe:
    """``node_oom_kills`` as the dispatcher calls it: pinned to a node, it answers the node's count (``counts``)."""

    def __init__(self, counts) -> None:
        self.counts, self.nodes = iter(counts), []

    def options(self, scheduling_strategy):
        self.nodes.append((scheduling_strategy.node_id, scheduling_strategy.soft))
        return self

    def remote(self):
        return ray.put(next(self.counts))


class KernelKills:
    """``run_job_task`` whose every attempt is :class:`KilledByTheKernel` (the node's count at its start: 10 x the
    attempt's number); records each attempt's options."""

    def __init__(self) -> None:
        self.options_seen = []

    def options(self, **options):
        seen = self.options_seen

        class Submit:
            @staticmethod
            def remote(spec):
                seen.append(options)
                return KilledByTheKernel(spec, kills=10 * spec["attempt"])

        return Submit


@pytest.mark.parametrize("killed", [True, False])
def test_a_worker_the_kernel_killed_for_memory_is_told_apart_from_a_crash(client_factory, monkeypatch, killed):
    """The node's OOM-kill count rose between the attempt's start and its loss (asked of that very node): the job
    ran out of memory, and says so; else it is a lost worker as before."""
    task, probe = KernelKills(), NodeProbe([10 * a + (1 if killed else 0) for a in (1, 2, 3)])
    monkeypatch.setattr(workers.ray_tasks, "run_job_task", task)
    monkeypatch.setattr(workers.ray_tasks, "node_oom_kills", probe)
    client = client_factory(job_max_attempts=3)
    job = wait_final(client, client.post("/v1/photos/batches", files=batch_files(2), data=FACES_ONLY).json()["id"])
    assert job["state"] == "failed" and job["attempts"] == 3, job
    assert probe.nodes == [(NODE, False)] * 3  # each time the lost attempt's own node, and no other
    if killed:
        assert job["error"].startswith("the job ran out of memory") and "OOM killer; of 3 times lost" in job["error"]
    else:
        assert job["error"] == "the worker running this job was lost 3 times; giving up", job
    node_cpus = max(n["Resources"].get("CPU", 0) for n in ray.nodes() if n["Alive"])
    cpus = [options["num_cpus"] for options in task.options_seen]
    assert cpus == ([1, node_cpus, node_cpus] if killed else [1, 1, 1])  # after running out of memory: alone


_FREE_AND_TRIM = """
import json, os
from harness.proc import status_mb
from workers.runtime import give_back_freed_memory

def resident_mb():
    return status_mb(os.getpid(), "VmRSS")

before = resident_mb()
blocks = [os.urandom(100_000) for _ in range(2000)]  # 200 MB in blocks under glibc's threshold for mapping alone
last = blocks[-1]  # still in use at the heap's top: glibc cannot shrink the heap past it
del blocks
kept = resident_mb()
give_back_freed_memory()
print(json.dumps([before, kept, resident_mb(), len(last)]))
"""


def test_memory_a_finished_job_freed_goes_back_to_the_system():
    import json
    import subprocess
    import sys

    from workers.runtime import _LIBC

    if not os.path.exists("/proc/self/status") or not hasattr(_LIBC, "malloc_trim"):
        pytest.skip("needs Linux with glibc")
    # in a process of its own: the suite's own heap has free blocks the 200 MB would partly reuse
    out = subprocess.run([sys.executable, "-c", _FREE_AND_TRIM], capture_output=True, text=True, check=True, cwd=ROOT)
    before, kept, after, size = json.loads(out.stdout)
    assert kept - before > 150, (before, kept)  # freed, yet still resident
    assert kept - after > 150, (kept, after)  # given back
    assert size == 100_000
