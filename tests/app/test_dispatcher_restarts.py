"""The dispatcher's retry budget across service restarts, without Ray: attempts are scripted."""
from __future__ import annotations

import asyncio

import pytest

from app.dispatcher import Dispatcher
from app.events import EventHub
from app.jobstore import JobState, JobStore

LEASE_S = 0.3


class Scripted(Dispatcher):
    """Runs each attempt as the script says: "lost" (the worker died), "hang" (until the process
    is "killed") or "ok"."""

    def __init__(self, script: dict[int, str], *args) -> None:
        super().__init__(*args)
        self.script = script
        self.ray_ready.set()

    async def _run_attempt(self, job) -> bool:
        outcome = self.script[job.attempts]
        if outcome == "lost":
            return False
        if outcome == "hang":
            await asyncio.Event().wait()
        await asyncio.to_thread(self.jobs.finish, job.id, self.owner, JobState.succeeded, {"files": []})
        return True


@pytest.fixture
def jobs(tmp_path):
    store = JobStore(f"sqlite:///{tmp_path / 'jobs.db'}")
    yield store
    store.close()


def _dispatcher(settings_factory, jobs, script, max_attempts=3) -> Scripted:
    settings = settings_factory(job_lease_seconds=LEASE_S, job_max_attempts=max_attempts)
    return Scripted(script, settings, jobs, EventHub(), "file:///unused")


async def _kill(dispatcher: Dispatcher) -> None:
    """Like kill -9 of the API: its tasks stop, nothing is released, the leases run out."""
    for task in list(dispatcher._tasks.values()):
        task.cancel()
    await asyncio.sleep(LEASE_S + 0.1)


async def _until(predicate, timeout: float = 10.0) -> None:
    for _ in range(int(timeout / 0.02)):
        if predicate():
            return
        await asyncio.sleep(0.02)
    raise AssertionError("timed out")


def test_one_lost_worker_and_two_kill_9_restarts_do_not_fail_a_healthy_job(settings_factory, jobs):
    script = {1: "lost", 2: "hang", 3: "hang", 4: "ok"}
    job = jobs.create("orientation.batch", {}, {}, {}, "api-0", 0.01)

    async def scenario() -> None:
        await asyncio.sleep(0.05)
        for hanging in (2, 3):  # two API processes, each killed while an attempt runs
            d = _dispatcher(settings_factory, jobs, script)
            assert await d.recover() == 1
            await _until(lambda: jobs.get(job.id).attempts == hanging)
            await _kill(d)
        last = _dispatcher(settings_factory, jobs, script)
        assert await last.recover() == 1
        await _until(lambda: jobs.get(job.id).state == "succeeded")

    asyncio.run(scenario())
    done = jobs.get(job.id)
    assert done.state == "succeeded", done.error
    assert (done.attempts, done.worker_losses, done.service_restarts) == (4, 1, 2)


def test_lost_workers_spend_the_budget_and_the_error_names_the_restarts(settings_factory, jobs):
    script = {1: "hang", 2: "lost", 3: "lost"}
    job = jobs.create("orientation.batch", {}, {}, {}, "api-0", 0.01)

    async def scenario() -> None:
        await asyncio.sleep(0.05)
        first = _dispatcher(settings_factory, jobs, script, max_attempts=2)
        await first.recover()
        await _until(lambda: jobs.get(job.id).attempts == 1)
        await _kill(first)
        second = _dispatcher(settings_factory, jobs, script, max_attempts=2)
        await second.recover()
        await _until(lambda: jobs.get(job.id).state == "failed")

    asyncio.run(scenario())
    failed = jobs.get(job.id)
    assert (failed.attempts, failed.worker_losses, failed.service_restarts) == (3, 2, 1)
    assert failed.error.startswith("the worker running this job was lost 2 times; giving up")
    assert "the service also restarted once while it ran" in failed.error

