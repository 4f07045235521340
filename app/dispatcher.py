"""Submitting jobs to Ray, following their events, retrying lost workers, recovering on start.

One dispatcher per API process. It owns the jobs it holds the lease of: it renews their
leases while it follows them and gives them back on a clean shutdown. A sweep claims jobs
whose lease expired (their owner died), so jobs survive a restart of the service or the
loss of a replica; the job table, not Ray, is the source of truth.

Only lost workers spend a job's retry budget (``job_max_attempts``). An attempt cut short because
the service stopped or died is counted apart (``service_restarts``, by the job store when the
lease is given back or claimed): restarting the service never fails a healthy job.

A database outage fails no job either: every job-table write waits until the database answers again
(progress writes are skipped meanwhile), and the sweep claims nothing until the database has answered for a
whole lease, so each replica renews the leases of the jobs it still follows (they expired during the outage)
before another replica could take them.
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import shutil
import socket
import tempfile
import time
import uuid
from dataclasses import asdict
from pathlib import Path
from typing import Any

import ray
import ray.exceptions

from app.events import EventHub
from app.jobstore import Job, JobState, JobStore, database_unavailable, job_public
from app.settings import Settings
from workers.registry import get_kind
from workers.runtime import JobSpec, publish_results
from workers.storage import check_key, open_store

log = logging.getLogger("sweepcast.dispatcher")

# A lost worker or node: worth another attempt. Anything else from Ray is a bug or a cancel.
_RETRYABLE = (
    ray.exceptions.WorkerCrashedError,
    ray.exceptions.NodeDiedError,
    ray.exceptions.ObjectLostError,
    ray.exceptions.OwnerDiedError,
    ray.exceptions.LocalRayletDiedError,
    ray.exceptions.RaySystemError,
)
_PROGRESS_WRITE_INTERVAL_S = 0.25
_DATABASE_RETRY_MAX_S = 5.0


OOM_PROBE_S = 10.0
"""How long the dispatcher waits for a lost attempt's node to say how many OOM kills it has seen."""


async def _killed_for_memory(exc: BaseException, node_id: str | None, kills_at_start: int | None) -> bool:
    """Whether the kernel's OOM killer ended a process on ``node_id`` since the lost attempt started there (its
    ``started`` event's count, ``kills_at_start``): asked of the node itself (:func:`_node_oom_kills`). Only for a
    crashed worker (``exc`` a WorkerCrashedError: its node is still there to ask). False when it cannot tell: no
    count at the start, or no answer within ``OOM_PROBE_S``."""
    if not isinstance(exc, ray.exceptions.WorkerCrashedError) or node_id is None or kills_at_start is None:
        return False
    try:  # off the event loop: submitting a task waits for the cluster's head when it is away
        now = await asyncio.wait_for(asyncio.to_thread(_node_oom_kills, node_id), OOM_PROBE_S)
    except Exception:  # noqa: BLE001 - the node died with its worker, or does not answer: not known to be memory
        return False
    return now is not None and now > kills_at_start


def _node_oom_kills(node_id: str) -> int | None:
    """:func:`workers.ray_tasks.node_oom_kills` run on ``node_id`` (pinned to it); blocking, at most ``OOM_PROBE_S``."""
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    from workers.ray_tasks import node_oom_kills

    ref = node_oom_kills.options(scheduling_strategy=NodeAffinitySchedulingStrategy(node_id, soft=False)).remote()
    try:
        return ray.get(ref, timeout=OOM_PROBE_S)
    except Exception:
        with contextlib.suppress(Exception):
            ray.cancel(ref, force=True)
        raise


class _Unschedulable(Exception):
    """No live node offers what the job needs."""


def _gave_up(job: Job, out_of_memory: int = 0) -> str:
    """The error of a job whose retry budget lost workers spent; restarts are named, not counted. ``out_of_memory``:
    how many of those losses were for want of memory (Ray's memory monitor stopped the job as its node ran out of
    memory, or the kernel's OOM killer ended its worker at the node's memory limit)."""
    if out_of_memory:
        alone = ", the attempts after that alone on a node" if job.worker_losses > 1 else ""
        error = (f"the job ran out of memory: its worker's node was out of memory and its worker was stopped "
                 f"{_times(out_of_memory)} (by Ray's memory monitor or the kernel's OOM killer; of "
                 f"{_times(job.worker_losses)} lost{alone}); giving up. It needs more "
                 "memory than a worker has: give the job smaller inputs or the workers more memory")
    else:
        error = f"the worker running this job was lost {_times(job.worker_losses)}; giving up"
    if job.service_restarts:
        error += (f" (the service also restarted {_times(job.service_restarts)} while it ran; "
                  "restarts do not count against the attempts)")
    return error


def _times(n: int) -> str:
    return "once" if n == 1 else f"{n} times"


def _describe(options: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v:g}" for k, v in {"CPU": options.get("num_cpus", 1), **options.get("resources", {})}.items())


def _offering(need: dict[str, float]) -> list[dict[str, float]]:
    """The resources of each live node that has, in total, every resource in ``need``."""
    nodes = [node.get("Resources", {}) for node in ray.nodes() if node.get("Alive")]
    return [have for have in nodes if all(have.get(k, 0.0) >= v for k, v in need.items() if v > 0)]


def _schedulable(options: dict[str, Any]) -> bool:
    """Whether some live node has, in total, every resource the task asks for."""
    need = {"CPU": float(options.get("num_cpus", 1)), **{k: float(v) for k, v in options.get("resources", {}).items()}}
    return bool(_offering(need))


def _whole_node(options: dict[str, Any]) -> dict[str, Any]:
    """``options`` asking for every CPU of the largest live node that offers its other resources: an attempt that
    runs alone there (every job asks for CPUs, so none is placed beside it). Unchanged when no node offers them."""
    cpus = [have.get("CPU", 0.0) for have in _offering({k: float(v) for k, v in options.get("resources", {}).items()})]
    return {**options, "num_cpus": max(cpus)} if cpus and max(cpus) > options.get("num_cpus", 1) else options


def _publish_files(store_url: str, job_id: str, results: dict[str, Path], summary: dict[str, Any]) -> dict[str, Any]:
    """``results`` (name -> local file) published as the job's results, as a worker publishes them; the manifest."""
    with tempfile.TemporaryDirectory(prefix=f"sweepcast-{job_id[:8]}-") as name:
        staging = Path(name)
        for result, path in results.items():
            shutil.copyfile(path, staging / check_key(result))
        return publish_results(open_store(store_url), job_id, staging, summary)


class Dispatcher:
    def __init__(self, settings: Settings, jobs: JobStore, hub: EventHub, store_url: str) -> None:
        self.settings = settings
        self.jobs = jobs
        self.hub = hub
        self.store_url = store_url
        self.owner = f"{socket.gethostname()}-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self._tasks: dict[str, asyncio.Task] = {}
        self._refs: dict[str, Any] = {}
        self._cancelled: set[str] = set()
        self._loops: list[asyncio.Task] = []
        self.ray_ready = asyncio.Event()
        """Set once Ray is connected; attempts wait for it (a submit before that would start a stray Ray)."""
        self._out_of_memory: dict[str, int] = {}
        """Attempts of each job this dispatcher follows that Ray stopped for want of memory (for the error)."""
        self._database_failed_at = -float("inf")
        """When a job-table call last found the database unreachable (monotonic seconds)."""

    @property
    def lease_s(self) -> float:
        return self.settings.job_lease_seconds

    async def start(self) -> None:
        """Recover what earlier runs left, then keep leases fresh and sweep for orphans."""
        await self.recover()
        self._loops = [asyncio.create_task(self._renew_loop()), asyncio.create_task(self._sweep_loop())]

    async def recover(self) -> int:
        """Claim and resubmit every active job whose lease expired; return how many."""
        claimed = await asyncio.to_thread(self.jobs.claim_expired, self.owner, self.lease_s)
        for job in claimed:
            if job.id not in self._tasks:
                log.info("recovering job %s (%s, %d attempts so far: %d lost workers, %d service restarts)",
                         job.id, job.kind, job.attempts, job.worker_losses, job.service_restarts)
                self.submit(job.id)
        return len(claimed)

    def submit(self, job_id: str) -> None:
        """Start following a committed job this dispatcher holds the lease of."""
        task = asyncio.create_task(self._drive(job_id), name=f"job-{job_id}")
        self._tasks[job_id] = task
        task.add_done_callback(lambda _t: self._tasks.pop(job_id, None))

    async def cancel(self, job_id: str) -> bool:
        """Stop a job: kill its Ray task and mark it cancelled. False when it had already finished."""
        self._cancelled.add(job_id)
        ref = self._refs.get(job_id)
        if ref is not None:
            try:
                ray.cancel(ref, force=True)
            except Exception as exc:  # noqa: BLE001 - the task may have just finished
                log.debug("cancel of %s: %s", job_id, exc)
        done = await asyncio.to_thread(self.jobs.finish, job_id, None, JobState.cancelled, None, "cancelled by the user")
        if done:
            await self._publish_final(job_id)
        return done

    async def shutdown(self, cancel_tasks: bool = True) -> None:
        """Stop following jobs and give their leases back so the next start resumes them at once. ``cancel_tasks``
        False: leave their Ray tasks alone (a client that lost its cluster's head may hang on them)."""
        for loop in self._loops:
            loop.cancel()
        held = list(self._tasks)
        for job_id in held:
            ref = self._refs.get(job_id) if cancel_tasks else None
            if ref is not None:
                try:
                    ray.cancel(ref, force=True)
                except Exception:  # noqa: BLE001
                    pass
            self._tasks[job_id].cancel()
        await asyncio.gather(*[t for t in list(self._tasks.values())], return_exceptions=True)
        for job_id in held:
            try:
                await asyncio.to_thread(self.jobs.release, job_id, self.owner)
            except Exception as exc:  # noqa: BLE001 - unreleased, its lease lapses and the sweep resumes it
                self._database_failed(exc, f"giving back job {job_id}")

    async def finish_here(self, job_id: str, results: dict[str, Path], summary: dict[str, Any]) -> bool:
        """Complete a committed job this dispatcher holds, not yet submitted, in this process, as one attempt whose
        results are the files ``results`` (result name -> local file), without Ray: for a job whose result is
        already at hand (the demo recording, kept from an earlier render). False when that failed: nothing was
        published and the job is still active and ours (submit it)."""
        job = await asyncio.to_thread(self.jobs.begin_attempt, job_id, self.owner, self.lease_s)
        if job is None:
            return False
        try:
            await asyncio.to_thread(self.jobs.mark_running, job_id, self.owner)
            manifest = await asyncio.to_thread(_publish_files, self.store_url, job_id, results, summary)
        except Exception:  # noqa: BLE001 - the job is still ours and active: the caller submits it
            log.exception("could not complete job %s in the service", job_id)
            return False
        result = {**manifest, "attempt": job.attempts, "worker": {"node_id": None, "pid": os.getpid()}}
        if not await asyncio.to_thread(self.jobs.finish, job_id, self.owner, JobState.succeeded, result, None):
            return False
        await self._publish_final(job_id)
        return True

    async def _renew_loop(self) -> None:
        while True:
            await asyncio.sleep(self.lease_s / 3)
            try:
                await asyncio.to_thread(self.jobs.renew_leases, list(self._tasks), self.owner, self.lease_s)
            except Exception as exc:  # noqa: BLE001 - a database hiccup must not end the loop
                self._database_failed(exc, "lease renewal")

    async def _sweep_loop(self) -> None:
        while True:
            await asyncio.sleep(max(self.lease_s / 2, 0.5))
            if time.monotonic() - self._database_failed_at < self.lease_s:
                continue  # leases that lapsed in an outage are their owners' to renew first
            try:
                await self.recover()
            except Exception as exc:  # noqa: BLE001
                self._database_failed(exc, "recovery sweep")

    def _database_failed(self, exc: Exception, what: str) -> None:
        """Note a failed job-table call of a loop (logged: a traceback only when it is not an outage)."""
        if database_unavailable(exc):
            self._database_failed_at = time.monotonic()
            log.warning("%s: the job database is unreachable (%s)", what, type(exc).__name__)
        else:
            log.exception("%s failed", what)

    async def _db(self, call: Any, *args: Any) -> Any:
        """``call(*args)`` on the job table off the event loop, waiting out a database outage (retried with
        backoff up to every 5 s, for as long as it lasts: a job's bookkeeping is never dropped)."""
        delay, since = 0.25, None
        while True:
            try:
                result = await asyncio.to_thread(call, *args)
            except Exception as exc:
                if not database_unavailable(exc):
                    raise
                self._database_failed_at = time.monotonic()
                if since is None:
                    since = time.monotonic()
                    log.warning("the job database is unreachable (%s: %s); %s waits for it", type(exc).__name__,
                                str(exc).splitlines()[0][:200], getattr(call, "__name__", "a job-table call"))
                await asyncio.sleep(delay)
                delay = min(delay * 2, _DATABASE_RETRY_MAX_S)
                continue
            if since is not None:
                log.info("the job database answers again after %.1f s", time.monotonic() - since)
            return result

    async def _drive(self, job_id: str) -> None:
        try:
            await self.ray_ready.wait()
            budget = self.settings.job_max_attempts
            while True:
                job = await self._db(self.jobs.begin_attempt, job_id, self.owner, self.lease_s, budget)
                if job is None or job_id in self._cancelled:
                    return
                if job.worker_losses >= budget:
                    await self._fail(job_id, _gave_up(job, self._out_of_memory.get(job_id, 0)))
                    return
                if await self._run_attempt(job):
                    return
                await self._db(self.jobs.record_worker_loss, job_id, self.owner)
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # noqa: BLE001 - never leave a row in "running" because of a bug here
            log.exception("dispatcher failed on job %s", job_id)
            await self._fail(job_id, f"internal error in the dispatcher: {type(exc).__name__}: {exc}")
        finally:
            self._refs.pop(job_id, None)
            self._out_of_memory.pop(job_id, None)

    async def _run_attempt(self, job: Job) -> bool:
        """Run one attempt; True when the job reached a final state, False to try again."""
        kind = get_kind(job.kind)
        spec = JobSpec(job.id, job.kind, job.params, job.inputs, job.input_meta or {}, job.attempts, self.store_url)
        options: dict[str, Any] = {"num_cpus": kind.num_cpus}
        if self.settings.job_resources:
            options["resources"] = dict(self.settings.job_resources)
        if self._out_of_memory.get(job.id):  # its node ran out of memory: alone, it has the node's memory to itself
            options = await asyncio.to_thread(_whole_node, options)
            log.warning("job %s: its last attempt ran out of memory (its node's); this attempt runs alone "
                        "on a node (%s)", job.id, _describe(options))
        from workers.ray_tasks import run_job_task

        missing = await self._wait_schedulable(options)
        if missing:
            await self._fail(job.id, missing)
            return True
        gen = run_job_task.options(**options).remote(asdict(spec))
        self._refs[job.id] = gen
        last_write = 0.0
        worker: dict[str, Any] = {}
        oom_kills_at_start: int | None = None
        try:
            async for ref in self._events(gen, options):
                event = await ref
                etype = event.get("type")
                if etype == "started":
                    worker = {"node_id": event.get("node_id"), "pid": event.get("pid")}
                    oom_kills_at_start = event.get("oom_kills")
                    await self._db(self.jobs.mark_running, job.id, self.owner)
                    self.hub.publish(job.id, {**event, "job_id": job.id, "state": "running"})
                elif etype == "progress":
                    self.hub.publish(job.id, {**event, "job_id": job.id, "attempt": job.attempts})
                    now = time.monotonic()
                    if now - last_write >= _PROGRESS_WRITE_INTERVAL_S or event["fraction"] >= 1.0:
                        last_write = now
                        await self._progress(job.id, event["fraction"], event["stage"])
                elif etype == "succeeded":
                    result = {**event["manifest"], "attempt": job.attempts, "worker": worker}
                    await self._db(self.jobs.finish, job.id, self.owner, JobState.succeeded, result, None)
                    await self._publish_final(job.id)
                    return True
                elif etype == "failed":
                    await self._fail(job.id, event["error"])
                    return True
        except ray.exceptions.TaskCancelledError:
            return True
        except _Unschedulable as exc:
            await self._fail(job.id, str(exc))
            return True
        except (*_RETRYABLE, ray.exceptions.OutOfMemoryError) as exc:
            if job.id in self._cancelled:
                return True
            memory = (isinstance(exc, ray.exceptions.OutOfMemoryError)
                      or await _killed_for_memory(exc, worker.get("node_id"), oom_kills_at_start))
            if memory:  # worth another try: the node may have been busy
                self._out_of_memory[job.id] = self._out_of_memory.get(job.id, 0) + 1
            log.warning("job %s attempt %d lost its worker: %s%s", job.id, job.attempts, type(exc).__name__,
                        " (out of memory)" if memory else "")
            self.hub.publish(job.id, {"type": "retrying", "job_id": job.id, "attempt": job.attempts,
                                      "reason": type(exc).__name__, "worker_losses": job.worker_losses + 1,
                                      "service_restarts": job.service_restarts, "time": time.time()})
            return False
        except ray.exceptions.RayTaskError as exc:
            await self._fail(job.id, f"internal error on the worker: {exc.cause!r}" if exc.cause else str(exc))
            return True
        if job.id in self._cancelled:
            return True
        log.warning("job %s attempt %d ended without a final event", job.id, job.attempts)
        return False  # counted as a lost worker: it spends the budget, so a job cannot loop forever

    async def _progress(self, job_id: str, fraction: float, stage: str) -> None:
        """Store a job's progress; skipped while the database is unreachable (the events still reach clients)."""
        try:
            await asyncio.to_thread(self.jobs.set_progress, job_id, self.owner, fraction, stage)
        except Exception as exc:
            if not database_unavailable(exc):
                raise
            self._database_failed_at = time.monotonic()

    async def _wait_schedulable(self, options: dict[str, Any]) -> str | None:
        """Wait until some live node offers the resources; after the limit, say why it cannot run."""
        limit = self.settings.job_unschedulable_seconds
        deadline = time.monotonic() + limit
        while not await asyncio.to_thread(_schedulable, options):
            if time.monotonic() > deadline:
                return (f"no live Ray node offers the resources this job needs ({_describe(options)}) "
                        f"for {limit:g} s; add one with 'sweepcast worker --address ... --resources ...'")
            await asyncio.sleep(1.0)
        return None

    async def _events(self, gen: Any, options: dict[str, Any]) -> Any:
        """The attempt's event refs; while waiting for the first one, give up if the job became
        unschedulable (its node died before it started) for longer than the limit."""
        first = asyncio.ensure_future(gen.__anext__())
        unschedulable_since: float | None = None
        while True:
            done, _ = await asyncio.wait({first}, timeout=1.0)
            if done:
                break
            if await asyncio.to_thread(_schedulable, options):
                unschedulable_since = None
            elif unschedulable_since is None:
                unschedulable_since = time.monotonic()
            elif time.monotonic() - unschedulable_since > self.settings.job_unschedulable_seconds:
                ray.cancel(gen, force=True)
                raise _Unschedulable(f"no live Ray node offers the resources this job needs ({_describe(options)})")
        try:
            yield first.result()
        except StopAsyncIteration:
            return
        async for ref in gen:
            yield ref

    async def _fail(self, job_id: str, error: str) -> None:
        if await self._db(self.jobs.finish, job_id, self.owner, JobState.failed, None, error):
            await self._publish_final(job_id)

    async def _publish_final(self, job_id: str) -> None:
        job = await self._db(self.jobs.get, job_id)
        if job is not None:
            self.hub.publish(job_id, {"type": "final", "job_id": job_id, "time": time.time(), "job": job_public(job)})
