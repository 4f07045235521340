"""A job's stages as tasks: every item's result in its place, each run recorded with its node, the user's error as
itself, a bug as an error naming its stage."""
from __future__ import annotations

import pytest

from workers import fanout
from workers.common.jobctx import JobInputError
from workers.fanout import FanoutError, InProcess, OnRay, stage_summary


def square(x: int) -> int:
    return x * x


def refuse(x: int) -> int:
    if x == 3:
        raise JobInputError("photo 3 is not a photo")
    return x


def crash(x: int) -> int:
    raise ZeroDivisionError("a bug")


def test_in_process_runs_every_item_in_order_and_records_it():
    fan = InProcess()
    seen = []
    assert fan.map("squares", square, [1, 2, 3], lambda i, r: seen.append((i, r))) == [1, 4, 9]
    assert seen == [(0, 1), (1, 4), (2, 9)]
    summary = stage_summary(fan.runs["squares"])
    # one node: "local", or this process's Ray node when another test of this worker started Ray
    assert summary["tasks"] == 3 and list(summary["tasks_per_node"].values()) == [3] and summary["peak_rss_mb"] > 0


def test_on_ray_puts_every_result_in_its_place_and_records_the_node(ray_local):
    fan = OnRay()
    done = []
    assert fan.map("squares", square, list(range(6)), lambda i, r: done.append(i)) == [i * i for i in range(6)]
    assert sorted(done) == list(range(6))
    assert all(len(r.node) == 56 for r in fan.runs["squares"])  # a Ray node id, not "local"
    with pytest.raises(JobInputError, match="^photo 3 is not a photo$"):  # the user's error, not wrapped
        fan.map("refuse", refuse, list(range(6)))


def test_on_ray_keeps_one_task_submitted_per_cpu_and_runs_them_all(ray_local):
    import ray

    outstanding = []

    def wait(refs, timeout_s):  # what the job's main thread does, recording how many tasks it waits on
        outstanding.append(len(refs))
        return ray.wait(refs, num_returns=1, timeout=timeout_s)

    fan = OnRay(wait)
    items = list(range(3 * fan.parallelism + 1))
    assert fan.map("squares", square, items) == [i * i for i in items]
    # the rest are submitted as these finish, never queued at once for Ray to start worker processes for
    assert max(outstanding) == fan.in_flight == fanout.IN_FLIGHT_PER_CPU * fan.parallelism
    assert sum(1 for n in outstanding if n == fan.in_flight) >= len(items) - fan.in_flight


def test_a_bug_in_a_task_fails_the_stage_naming_it(ray_local, monkeypatch):
    # One retry, not none: Ray's forced cancel is asynchronous, and the worker it ends (the test before this one
    # cancels its stage's other tasks) was once handed this task first (CI, 2026-12-07: WorkerCrashedError). The bug
    # fails both attempts; a lost worker is tried again, as a job's tasks are.
    monkeypatch.setattr(fanout, "TASK_RETRIES", 1)
    with pytest.raises(FanoutError, match="stage 'crash': ZeroDivisionError: a bug"):
        OnRay().map("crash", crash, [1])
