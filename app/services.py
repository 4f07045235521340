"""The service's long-lived parts, created at start-up and shared by the routes."""
from __future__ import annotations

import asyncio
import logging
import os
import shutil
import uuid
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, BinaryIO, Callable, TypeVar

from fastapi import Request
from pydantic import BaseModel

from app.dispatcher import Dispatcher
from app.errors import ApiError
from app.events import EventHub
from app.frame_atlases import AtlasCache
from app.auth import Authenticator
from app.jobstore import Job, JobStore
from app.keys import KeyStore, Principal
from app.kernelcache import KernelWarmup
from app.live_relay import LiveRelay
from app.quotas import QuotaLimits, Quotas
from app.settings import Settings
from app.sync_work import SyncWorkGate, SyncWorkLimits
from workers.registry import JobKind
from workers.runtime import inputs_prefix, results_prefix
from workers.workarea import work_prefix
from workers.storage import BlobStore, DirectoryBlobStore, open_store

log = logging.getLogger("sweepcast")
R = TypeVar("R")


@dataclass
class Services:
    settings: Settings
    jobs: JobStore
    store: BlobStore
    hub: EventHub
    dispatcher: Dispatcher
    compute: ThreadPoolExecutor
    """Runs every route's CPU work in this process (:func:`run_compute`): one thread per core, so that a burst of
    requests neither oversubscribes the CPU nor builds a detector per thread of a large pool."""
    keys: KeyStore
    auth: Authenticator
    quotas: Quotas
    sync_work: SyncWorkGate
    """Bounds the synchronous depth routes' work and how much of it runs at once (:mod:`app.sync_work`)."""
    ray_owned: bool = False
    ray_error: str | None = None
    warmup: KernelWarmup = field(default_factory=KernelWarmup)
    """The background compile of the engines' kernels started with the service (state "off" when not)."""
    atlases: AtlasCache = field(default_factory=lambda: AtlasCache(0))
    """Encoded frame sets of recordings for browser-rendering viewers (:mod:`app.frame_atlases`)."""
    live_relay: LiveRelay = field(default_factory=LiveRelay)
    """Live frame sets fanned out to browser-rendering viewers (:mod:`app.live_relay`)."""
    finished_imports: OrderedDict[str, Job] = field(default_factory=OrderedDict)
    """Recordings' import jobs this process last read finished, newest last (:func:`app.stored_rigs.import_job`):
    what a viewer socket is told while the database cannot be reached."""


def build_services(settings: Settings) -> Services:
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    jobs = JobStore(settings.resolved_database_url)
    store = open_store(settings.resolved_storage_url)
    hub = EventHub()
    compute = ThreadPoolExecutor(settings.request_threads or os.cpu_count() or 1, thread_name_prefix="compute")
    keys = KeyStore(jobs.engine)
    quotas = Quotas(QuotaLimits(settings.quota_stored_bytes, settings.quota_active_jobs, settings.quota_viewer_sessions,
                                settings.quota_uploads_per_minute), jobs)
    return Services(settings, jobs, store, hub, Dispatcher(settings, jobs, hub, store.url), compute,
                    keys, Authenticator(settings.api_keys, keys), quotas,
                    SyncWorkGate(SyncWorkLimits.from_settings(settings)),
                    atlases=AtlasCache(int(settings.viewer_frame_cache_mb * 2**20)))


async def run_compute(svc: Services, fn: Callable[..., R], *args: Any) -> R:
    """``fn(*args)`` on the service's compute threads (:attr:`Services.compute`), awaited without blocking
    the event loop: every route's CPU work (decoding, OpenCV, numba, parsing uploads) goes through here,
    never through Starlette's 40-thread pool; waiting on I/O (the job table, the blob store) uses
    ``asyncio.to_thread``."""
    return await asyncio.get_running_loop().run_in_executor(svc.compute, fn, *args)


CHECK_TIMEOUT_S = 3.0
_checks: dict[tuple[str, int], asyncio.Future] = {}
"""Backend checks in flight, by what they check and the object checked: at most one each."""


async def answer_within(check: Callable[[], R], what: str, timeout: float = CHECK_TIMEOUT_S) -> R | str | None:
    """``check()`` off the event loop, given ``timeout`` seconds: its result (None for none), or why it failed. A
    backend that hangs (a frozen database, a Ray head that is gone) gets a reason instead of holding the caller;
    a check still running from an earlier call is awaited rather than started again (each would hold a thread for
    as long as the backend hangs, and two callers at once must not see a backend as lost)."""
    key = (what, id(getattr(check, "__self__", check)))  # one app's database is not another's (tests)
    future = _checks.get(key)
    if future is None or future.done():
        future = _checks[key] = asyncio.ensure_future(asyncio.to_thread(check))
    try:
        return await asyncio.wait_for(asyncio.shield(future), timeout)
    except asyncio.TimeoutError:
        return f"{what} did not answer within {timeout:g} s"
    except Exception as exc:  # noqa: BLE001 - reported, not raised
        return f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"


async def delete_job_and_files(svc: Services, job_id: str) -> None:
    """Delete a job's row, then its results, its inputs and what its tasks left in its work area (a job that failed
    or was cancelled keeps it until then) from the blob store."""
    await asyncio.to_thread(svc.jobs.delete, job_id)
    await asyncio.to_thread(svc.store.delete_prefix, results_prefix(job_id))
    await asyncio.to_thread(svc.store.delete_prefix, inputs_prefix(job_id))
    await asyncio.to_thread(svc.store.delete_prefix, work_prefix(job_id))


def storage_check(svc: Services) -> dict[str, object]:
    """Free space of a file blob store against ``min_free_storage_mb``; an object store: whether it answers (its
    space is not ours to measure)."""
    if not isinstance(svc.store, DirectoryBlobStore):
        problem = svc.store.check()
        return {"ok": problem is None, "detail": problem or "object store answers"}
    free = shutil.disk_usage(svc.store.root).free
    need = svc.settings.min_free_storage_mb * 2**20
    ok = free >= need
    detail = f"{free / 2**20:,.0f} MB free" + ("" if ok else f", under the {need / 2**20:,.0f} MB the service keeps "
                                                               "free: new jobs are refused (507) until space is freed")
    return {"ok": ok, "free_bytes": free, "detail": detail}


def services(request: Request) -> Services:
    return request.app.state.services


@dataclass
class Upload:
    """One input of a new job: its name in the job, a readable file and what to record about it."""

    name: str
    file: BinaryIO | bytes
    meta: dict[str, Any] = field(default_factory=dict)


def upload_size(upload: Upload) -> int:
    """Bytes of an upload (a spooled file is measured by seeking; its position is kept)."""
    if isinstance(upload.file, (bytes, bytearray)):
        return len(upload.file)
    position = upload.file.tell()
    size = upload.file.seek(0, os.SEEK_END)
    upload.file.seek(position)
    return size


async def create_job(svc: Services, who: Principal, kind: JobKind, params: BaseModel, uploads: list[Upload],
                     stored: dict[str, str] | None = None, submit: bool = True) -> Job:
    """Check ``who``'s quotas, store the inputs, commit the row, then submit: the row exists before Ray hears of
    the job, and nothing is stored for a job the quotas refuse (429, 507).

    ``kind``: the engine's job constant (``workers/<engine>/job.py``); ``params``: the request already
    parsed into the kind's model (stored as JSON; the worker validates the row once more, as it may
    outlive this version). ``stored`` (input name -> key) names inputs already in the blob store (a
    recording's archive), which the job reads in place instead of a copy. ``submit`` False: the caller runs it
    (``svc.dispatcher.finish_here``, else ``submit``).
    """
    if not isinstance(params, kind.params):
        raise TypeError(f"{kind.name} takes {kind.params.__name__}, not {type(params).__name__}")
    await svc.quotas.check_new_job(who, sum(map(upload_size, uploads)))
    if isinstance(svc.store, DirectoryBlobStore):  # (an object store that is down says so at the first write: 503)
        space = await asyncio.to_thread(storage_check, svc)
        if not space["ok"]:
            raise ApiError(507, f"the service's storage is nearly full ({space['detail']}); nothing was stored",
                           "storage_full")
    job_id = str(uuid.uuid4())
    prefix = inputs_prefix(job_id)
    inputs: dict[str, str] = dict(stored or {})
    meta: dict[str, Any] = {name: {"stored": key} for name, key in inputs.items()}
    try:
        for up in uploads:
            key = f"{prefix}/{up.name}"
            size = await asyncio.to_thread(svc.store.put, key, up.file)
            inputs[up.name] = key
            meta[up.name] = {**up.meta, "size": size}
        job = await asyncio.to_thread(
            svc.jobs.create, kind.name, params.model_dump(mode="json"), inputs, meta, svc.dispatcher.owner,
            svc.settings.job_lease_seconds, job_id, who.id,
        )
    except BaseException:
        await asyncio.to_thread(svc.store.delete_prefix, prefix)
        raise
    if submit:
        svc.dispatcher.submit(job.id)
    return job
