"""Running one job attempt: the JobContext implementation and the event stream.

``execute_job`` runs a job function in a thread and yields its events as plain dicts:

- ``{"type": "started", "attempt", "node_id", "pid", "oom_kills"}`` once, first (``oom_kills``: the kernel's OOM kills
  in the node's memory cgroup so far, :func:`workers.oom.oom_kills`);
- ``{"type": "progress", "fraction", "stage"}`` as the job reports (a job that counts items adds ``done``, ``total``
  and ``eta_s``, the seconds it expects to need still, or null before it can tell);
- last, ``{"type": "succeeded", "manifest"}`` or ``{"type": "failed", "error", "user_error"}``.

Results are written to a local staging folder, copied to a temporary prefix of the blob
store and published to ``jobs/<id>/results`` only when the job function returned, so a
retried attempt replaces, never mixes with, an earlier one (delivery is at-least-once).
The Ray task in :mod:`workers.ray_tasks` is a thin wrapper around this generator.

A job that fans out (``ctx.fanout()``, :mod:`workers.fanout`) runs its tasks as Ray tasks when the attempt runs on Ray
(``on_ray``), else here one after another. Its tasks write into the job's work area in the blob store
(:mod:`workers.workarea`), which outlives the attempt, and the job publishes those files with its results
(``ctx.adopt_result``); the work area is deleted once they are published.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import mimetypes
import os
import queue
import shutil
import tempfile
import threading
import time
import traceback
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

from pydantic import BaseModel, ValidationError

from workers.common.jobctx import JobInputError
from workers.common.validation import describe_errors
from workers.fanout import FanOut, InProcess, OnRay
from workers.oom import oom_kills
from workers.registry import get_kind
from workers.settings import worker_settings
from workers.storage import BlobStore, check_key, open_store, storage_full, storage_unavailable
from workers.workarea import InputRef, WorkArea, work_prefix

_DONE = object()


class StorageOutage(RuntimeError):
    """The object store stayed unreachable for longer than the job waits for it."""


@dataclass
class JobSpec:
    """Everything a worker needs to run one attempt of a job (no bytes: keys only)."""

    job_id: str
    kind: str
    params: dict[str, Any]
    inputs: dict[str, str]
    input_meta: dict[str, dict[str, Any]] = field(default_factory=dict)
    attempt: int = 1
    store_url: str = ""


def results_prefix(job_id: str) -> str:
    return f"jobs/{job_id}/results"


def inputs_prefix(job_id: str) -> str:
    return f"jobs/{job_id}/inputs"


class StoreJobContext:
    """A :class:`workers.common.jobctx.JobContext` over a blob store and a staging folder; its fan-outs run on
    ``fan_out`` (default: in this process, one task after another)."""

    def __init__(self, spec: JobSpec, params: BaseModel, store: BlobStore, staging: Path,
                 emit: Callable[[dict], None], fan_out: FanOut | None = None):
        self.job_id = spec.job_id
        self.kind = spec.kind
        self.params = params  # the kind's model, validated once here
        self.inputs = dict(spec.inputs)
        self.input_meta = dict(spec.input_meta)
        self.settings = worker_settings()  # as the service set them in this worker's environment
        self._store = store
        self._staging = staging
        self._emit = emit
        self._last_fraction = 0.0
        self._fan_out = fan_out or InProcess()
        self._store_url = spec.store_url or store.url
        self.adopted: dict[str, tuple[str, int]] = {}
        """Result name -> (blob key in the work area, size): files the job's tasks wrote, published as results."""

    def _key(self, name: str) -> str:
        try:
            return self.inputs[name]
        except KeyError:
            raise KeyError(f"job {self.job_id} has no input named {name!r}") from None

    def input_path(self, name: str) -> Path:
        return self._store.local_path(self._key(name))

    def read_input(self, name: str) -> bytes:
        return self._store.read(self._key(name))

    def result_path(self, name: str) -> Path:
        path = self._staging / check_key(name)
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def write_result(self, name: str, data: bytes) -> None:
        self.result_path(name).write_bytes(data)

    def progress(self, fraction: float, stage: str, *, done: int | None = None, total: int | None = None,
                 eta_s: float | None = None) -> None:
        fraction = min(max(float(fraction), 0.0), 1.0)
        self._last_fraction = fraction
        event: dict[str, Any] = {"type": "progress", "fraction": fraction, "stage": str(stage)[:200]}
        if done is not None and total is not None:
            event.update(done=int(done), total=int(total), eta_s=None if eta_s is None else round(float(eta_s), 1))
        self._emit(event)

    def fanout(self) -> FanOut:
        return self._fan_out

    def work_area(self) -> WorkArea:
        return WorkArea(self._store_url, work_prefix(self.job_id), dict(self.inputs), opened=self._store)

    def input_ref(self, name: str) -> InputRef:
        label = self.input_meta.get(name, {}).get("filename") or name
        return InputRef(label, store_url=self._store_url, key=self._key(name))

    def adopt_result(self, name: str, work_name: str, size: int) -> None:
        self.adopted[check_key(name)] = (self.work_area().key(work_name), int(size))

    def reset(self) -> None:
        """Forget what a run that was cut short staged or adopted (its next run starts over)."""
        _empty(self._staging)
        self.adopted.clear()
        self._fan_out.runs.clear()


def _manifest(staging: Path, summary: dict[str, Any], adopted: dict[str, tuple[str, int]]) -> dict[str, Any]:
    sizes = {path.relative_to(staging).as_posix(): path.stat().st_size
             for path in staging.rglob("*") if path.is_file()}
    sizes.update({name: size for name, (_, size) in adopted.items()})
    files = [{"name": name, "size": size, "content_type": mimetypes.guess_type(name)[0] or "application/octet-stream"}
             for name, size in sorted(sizes.items())]
    return {"files": files, "summary": summary}


def _publish(store: BlobStore, job_id: str, staging: Path, adopted: dict[str, tuple[str, int]]) -> None:
    tmp_prefix = f"jobs/{job_id}/tmp-{uuid.uuid4().hex}"
    try:
        for path in sorted(p for p in staging.rglob("*") if p.is_file()):
            name = path.relative_to(staging).as_posix()
            if name not in adopted:
                with open(path, "rb") as f:
                    store.put(f"{tmp_prefix}/{name}", f)
        for name, (key, _) in sorted(adopted.items()):
            store.copy(key, f"{tmp_prefix}/{name}")
        store.publish(tmp_prefix, results_prefix(job_id))
    finally:
        store.delete_prefix(tmp_prefix)


def publish_results(store: BlobStore, job_id: str, staging: Path, summary: dict[str, Any],
                    adopted: dict[str, tuple[str, int]] | None = None) -> dict[str, Any]:
    """Publish the files in ``staging``, and the ``adopted`` blobs (result name -> (key, size); a name in both: the
    adopted blob), as the results of ``job_id``; the manifest the job row records."""
    adopted = adopted or {}
    manifest = _manifest(staging, summary, adopted)
    _publish(store, job_id, staging, adopted)
    return manifest


def _outlasting_storage(step: Callable[[], Any], what: str, budget_s: float, longest_wait_s: float) -> Any:
    """``step()``, tried again with backoff (1 s doubling up to ``longest_wait_s``) while the object store cannot
    be reached (every step here is safe to repeat: reads, and a publish that replaces), for up to ``budget_s``
    seconds of outage; then :class:`StorageOutage`."""
    delay, since = min(1.0, longest_wait_s), None
    while True:
        try:
            return step()
        except Exception as exc:
            if not storage_unavailable(exc):
                raise
            now = time.monotonic()
            since = now if since is None else since
            if now - since > budget_s:
                raise StorageOutage(f"the object store could not be reached for {now - since:.0f} s while "
                                    f"{what} ({type(exc).__name__}: {str(exc)[:200]}): nothing was published; run "
                                    "the job again once it is back") from exc
            print(f"sweepcast: the object store cannot be reached while {what} ({type(exc).__name__}); "
                  f"trying again in {delay:g} s", flush=True)
            time.sleep(delay)
            delay = min(delay * 2, longest_wait_s)


def _c_library() -> Any:
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
    except OSError:
        return None


_LIBC = _c_library()


def give_back_freed_memory() -> None:
    """Return to the system the heap memory a finished job freed. glibc keeps freed blocks in its arenas, and
    after a large array is freed it raises its threshold for mapping big blocks on their own, so the next jobs'
    arrays fragment the heap (in benchmarks/soak.py's hour, a job worker's memory grew 27 % past its warm-up).
    No-op where the C library has no ``malloc_trim`` (musl, macOS)."""
    trim = getattr(_LIBC, "malloc_trim", None)
    if trim is not None:
        trim(0)


def _empty(folder: Path) -> None:
    for entry in folder.iterdir():
        if entry.is_dir():
            shutil.rmtree(entry)
        else:
            entry.unlink()


def _node_id() -> str | None:
    try:
        import ray

        if ray.is_initialized():
            return ray.get_runtime_context().get_node_id()
    except Exception:  # noqa: BLE001 - outside Ray there is simply no node id
        pass
    return None


class _MainThreadCall:
    """A call the job's thread asks the attempt's main thread to make, and waits for."""

    def __init__(self, fn: Callable[[], Any]) -> None:
        self._fn = fn
        self._reply: queue.Queue = queue.Queue(maxsize=1)

    def run(self) -> None:
        try:
            self._reply.put((True, self._fn()))
        except BaseException as exc:  # noqa: BLE001 - handed to the thread that asked
            self._reply.put((False, exc))

    def result(self) -> Any:
        ok, value = self._reply.get()
        if not ok:
            raise value
        return value


def _ray_fan_out(events: queue.Queue) -> FanOut:
    """Fan-outs on Ray whose waits the attempt's main thread makes (see :class:`workers.fanout.OnRay`)."""
    import ray

    def wait(refs: list[Any], timeout: float) -> tuple[list[Any], list[Any]]:
        call = _MainThreadCall(lambda: ray.wait(refs, num_returns=1, timeout=timeout))
        events.put(call)
        return call.result()

    return OnRay(wait)


def _forget_work(store: BlobStore, job_id: str) -> None:
    """Delete the job's work area once its results are published (a leftover only costs space: deleted with the
    job)."""
    try:
        store.delete_prefix(work_prefix(job_id))
    except Exception as exc:  # noqa: BLE001 - the results are published: nothing to fail for
        print(f"sweepcast: job {job_id}: its work area stays until the job is deleted ({type(exc).__name__}: {exc})",
              flush=True)


def execute_job(spec: JobSpec, on_ray: bool = False) -> Iterator[dict[str, Any]]:
    """Run one attempt of ``spec`` and yield its events (see the module docstring). ``on_ray``: this is a Ray task,
    and the job's fan-outs run as Ray tasks."""
    yield {"type": "started", "attempt": spec.attempt, "node_id": _node_id(), "pid": os.getpid(),
           "oom_kills": oom_kills()}
    events: queue.Queue = queue.Queue()
    staging = Path(tempfile.mkdtemp(prefix=f"sweepcast-{spec.job_id[:8]}-"))
    outcome: dict[str, Any] = {}

    def work() -> None:
        try:
            kind = get_kind(spec.kind)
            store = open_store(spec.store_url)
            fan_out = _ray_fan_out(events) if on_ray else None
            ctx = StoreJobContext(spec, kind.validate(spec.params), store, staging, events.put, fan_out)
            budget = ctx.settings.storage_outage_seconds

            def run() -> dict[str, Any]:
                ctx.reset()  # a run cut short by the store leaves nothing for the next one
                return kind.entry(ctx) or {}

            summary = _outlasting_storage(run, "reading the job's inputs", budget, store.retry_after_s)
            manifest = _outlasting_storage(
                lambda: publish_results(store, spec.job_id, staging, summary, ctx.adopted),
                "publishing the results", budget, store.retry_after_s)
            _forget_work(store, spec.job_id)
            outcome["event"] = {"type": "succeeded", "manifest": manifest}
        except JobInputError as exc:
            outcome["event"] = {"type": "failed", "error": str(exc), "user_error": True}
        except ValidationError as exc:
            outcome["event"] = {"type": "failed", "error": f"invalid parameters: {describe_errors(exc)}",
                                "user_error": True}
        except Exception as exc:  # noqa: BLE001 - reported as the job's error, not raised into Ray
            if storage_full(exc):  # the deployment's condition, said in the error: no traceback in the log
                error = (f"the service's storage is full ({exc.strerror}): the results could not be written and "
                         "none were published; run the job again once space is freed")
            elif isinstance(exc, StorageOutage):
                error = str(exc)
            else:
                traceback.print_exc()
                error = f"internal error: {type(exc).__name__}: {exc}"
            outcome["event"] = {"type": "failed", "error": error, "user_error": False}
        finally:
            events.put(_DONE)

    thread = threading.Thread(target=work, name=f"job-{spec.job_id[:8]}", daemon=True)
    thread.start()
    try:
        while (event := events.get()) is not _DONE:
            if isinstance(event, _MainThreadCall):  # the job's fan-out waits: see _ray_fan_out
                event.run()
                continue
            event["time"] = time.time()
            yield event
        thread.join()
        yield {**outcome["event"], "time": time.time()}
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        give_back_freed_memory()
