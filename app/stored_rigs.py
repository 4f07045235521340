"""Rigs and recordings as stored, for the rig, recording and session routes, the sockets and the demo (not a
router): a rig's metadata with who may read or change it, recordings with their import job's state, what a socket
shows (:class:`Source`), the view limits and a session's configuration."""
from __future__ import annotations

import asyncio
import json
from dataclasses import dataclass
from typing import Any

from app.errors import ApiError
from app.jobstore import Job, JobState, database_unavailable
from app.keys import Principal
from app.services import Services, delete_job_and_files
from app.settings import Settings
from workers.streaming import store as rigstore
from workers.streaming.actor import LIVE, SessionConfig
from workers.streaming.job import DEMO_JOB, RECORDING_JOB
from workers.streaming.quality import LEVELS as QUALITY_LEVELS
from workers.streaming.rules import viewpoint_controls
from workers.streaming.session import SessionLimits
from workers.streaming.viewpoint import orbit_frame
from workers.sweep.rig import Rig
from workers.sweep.rig_io import rig_to_dict

async def rig_meta_or_404(svc: Services, rig_id: str, who: Principal, change: bool = False) -> dict[str, Any]:
    """The rig's metadata when ``who`` may read it (``change``: change it, add recordings or stream live frames to
    it). A rig another key created answers 404, as one that does not exist; the demo rig is readable by every
    key and changeable by admin keys only (403)."""
    meta = await asyncio.to_thread(rigstore.load_rig_meta, svc.store, rig_id)
    if meta is None or not (rig_readable(meta, who)):
        raise ApiError(404, f"no rig with id {rig_id!r}", "rig_not_found")
    if change and not who.owns(meta.get("created_by")):
        raise ApiError(403, f"rig {rig_id} is the demo rig: only an admin key may change it", "demo_rig_read_only")
    return meta


def rig_readable(meta: dict[str, Any], who: Principal) -> bool:
    return who.owns(meta.get("created_by")) or bool(meta.get("demo"))


async def load_rig(svc: Services, rig_id: str) -> Rig:
    return await asyncio.to_thread(rigstore.load_rig, svc.store, rig_id)


def rig_json_bytes(rig: Rig) -> bytes:
    return json.dumps(rig_to_dict(rig)).encode()


# --- recordings -----------------------------------------------------------------------------------
RECORDING_JOB_KINDS = (RECORDING_JOB.name, DEMO_JOB.name)


def rig_of_recording_job(store: Any, job: Job) -> str | None:
    """The rig whose recording ``job`` imported (a recording's id is its import job's id), or None.
    Blocking (reads the blob store)."""
    if job.kind not in RECORDING_JOB_KINDS:
        return None
    for rig in rigstore.list_rig_metas(store):
        if rigstore.load_recording_meta(store, rig["id"], job.id) is not None:
            return rig["id"]
    return None


def recording_view(meta: dict[str, Any], job: Job | None) -> dict[str, Any]:
    """The API view of a recording: its metadata plus the state of the job that imports it."""
    out = {k: meta.get(k) for k in ("id", "rig_id", "name", "kind", "created_at")}
    out.update(job_id=meta.get("job_id"), frames=None, fps=None, background=None, error=None,
               progress={"fraction": 0.0, "stage": ""})
    if job is None:
        return {**out, "state": "gone", "error": "its import job was deleted"}
    out["progress"] = {"fraction": job.progress, "stage": job.stage}
    state = JobState(job.state)
    if state == JobState.succeeded:
        summary = (job.result or {}).get("summary", {})
        return {**out, "state": "ready", "frames": summary.get("frames"), "fps": summary.get("fps"),
                "background": summary.get("background")}
    if state.finished:
        return {**out, "state": "failed", "error": job.error or state.value}
    return {**out, "state": "processing"}


KEPT_IMPORTS = 4096
"""Most finished import jobs a process keeps for database outages (:func:`import_job`; a few hundred bytes each)."""


async def import_job(svc: Services, job_id: str) -> Job | None:
    """A recording's import job, from the database; while the database cannot be reached, the one this process last
    read there if it had finished (a finished import never changes again, and deleting it needs the database), so
    that viewers of the recordings it served keep connecting through an outage. Else the outage's exception."""
    try:
        job = await asyncio.to_thread(svc.jobs.get, job_id)
    except Exception as exc:
        kept = svc.finished_imports.get(job_id)
        if kept is None or not database_unavailable(exc):
            raise
        return kept
    if job is not None and JobState(job.state).finished:
        svc.finished_imports[job_id] = job
        svc.finished_imports.move_to_end(job_id)
        while len(svc.finished_imports) > KEPT_IMPORTS:
            svc.finished_imports.popitem(last=False)
    else:
        svc.finished_imports.pop(job_id, None)
    return job


async def recording_views(svc: Services, rig_id: str) -> list[dict[str, Any]]:
    metas = await asyncio.to_thread(rigstore.list_recording_metas, svc.store, rig_id)
    return [recording_view(m, await import_job(svc, m["job_id"])) for m in metas]


async def recording_or_404(svc: Services, rig_id: str, recording_id: str) -> dict[str, Any]:
    meta = await asyncio.to_thread(rigstore.load_recording_meta, svc.store, rig_id, recording_id)
    if meta is None:
        raise ApiError(404, f"rig {rig_id} has no recording {recording_id!r}", "recording_not_found")
    return recording_view(meta, await import_job(svc, meta["job_id"]))


def require_ready(recording: dict[str, Any]) -> None:
    """409 unless the recording can be viewed or rendered."""
    if recording["state"] == "ready":
        return
    if recording["state"] == "processing":
        p = recording["progress"]
        detail = f"recording {recording['id']} is still being imported ({p['fraction']:.0%}: {p['stage']})"
    else:
        detail = f"recording {recording['id']} is unusable: {recording['error']}"
    raise ApiError(409, detail, "recording_not_ready")


async def delete_recording_data(svc: Services, rig_id: str, recording: dict[str, Any]) -> None:
    """Stop the import if it runs, then delete its job (row, inputs, archive) and the metadata."""
    job_id = recording["job_id"]
    job = await asyncio.to_thread(svc.jobs.get, job_id)
    if job is not None and not JobState(job.state).finished:
        await svc.dispatcher.cancel(job_id)
    await delete_job_and_files(svc, job_id)
    await asyncio.to_thread(rigstore.delete_recording_meta, svc.store, rig_id, recording["id"])


# --- sources and sessions -------------------------------------------------------------------------
@dataclass(frozen=True)
class Source:
    """What a socket shows: a rig and ``source`` ("live" or a recording id), with what a client
    needs to start (the rig's cameras and orbit frame, the recording's frames and rate, the view size
    to start at, what a viewer may ask for)."""

    rig_id: str
    source: str
    rig: Rig
    recording: dict[str, Any] | None
    view_size: tuple[int, int] = (640, 480)
    """The view size (width, height) px a viewer starts at (the ``viewer_size`` setting)."""
    max_planes: int | None = None
    """The most depth planes a viewer may ask for (the ``max_view_planes`` setting; None: the renderer's own limit)."""

    def hello(self) -> dict[str, Any]:
        return {
            "type": "hello", "rig_id": self.rig_id, "source": self.source, "view_size": list(self.view_size),
            "frames": self.recording["frames"] if self.recording else None,
            "fps": self.recording["fps"] if self.recording else None,
            "cameras": [{"name": c.name, "width": c.width, "height": c.height} for c in self.rig.cameras],
            "orbit": orbit_frame(self.rig).to_dict(),
            "quality_levels": QUALITY_LEVELS,
            "controls": viewpoint_controls(self.max_planes),
        }


async def resolve_source(svc: Services, rig_id: str, source: str | None, who: Principal,
                         change: bool = False) -> Source:
    """The rig and source a socket asked for (default: the newest ready recording, else live);
    ApiError (404 unknown rig or recording, 409 recording not ready) otherwise. ``change``: the socket changes
    the rig (live frames in), which the key must be allowed (:func:`rig_meta_or_404`); viewing is a read."""
    await rig_meta_or_404(svc, rig_id, who, change)
    rig = await load_rig(svc, rig_id)

    def shown(name: str, recording: dict[str, Any] | None) -> Source:
        return Source(rig_id, name, rig, recording, svc.settings.viewer_size_px, svc.settings.max_view_planes)

    if source == LIVE:
        return shown(LIVE, None)
    if source is None:
        ready = [r for r in await recording_views(svc, rig_id) if r["state"] == "ready"]
        return shown(ready[-1]["id"], ready[-1]) if ready else shown(LIVE, None)
    recording = await recording_or_404(svc, rig_id, source)
    require_ready(recording)
    return shown(source, recording)


def view_limits(settings: Settings) -> SessionLimits:
    """The service's view limits (``max_view_pixels``, ``max_view_planes``; their ``check`` is the one rule) and the
    largest spread of a live set's capture times (``live_max_spread_ms``) and the rate a session's "auto" quality holds
    (``viewer_target_fps``)."""
    return SessionLimits(max_pixels=settings.max_view_pixels, max_planes=settings.max_view_planes,
                         max_spread=settings.live_max_spread_ms / 1e3, target_fps=settings.viewer_target_fps)


def session_config(svc: Services, rig_id: str, source: str) -> SessionConfig:
    return SessionConfig(svc.store.url, rig_id, source, idle_seconds=svc.settings.session_idle_seconds,
                         limits=view_limits(svc.settings), render_slots=svc.settings.session_render_slots)
