"""Batch jobs: list, inspect, fetch results, cancel or delete, follow events."""
from __future__ import annotations

import asyncio
import datetime as dt
from typing import Any, Literal

from fastapi import APIRouter, Depends, Query, WebSocket, WebSocketDisconnect
from fastapi.responses import JSONResponse, Response, StreamingResponse
from pydantic import BaseModel, Field

from app.auth import principal, require_key, socket_principal
from app.errors import ApiError
from app.jobstore import Job, JobState, job_public
from app.keys import Principal
from app.stored_rigs import rig_of_recording_job
from app.services import Services, delete_job_and_files, services
from workers.runtime import results_prefix
from workers.storage import BlobNotFound

router = APIRouter(prefix="/v1/jobs", tags=["jobs"], dependencies=[Depends(require_key)])
ws_router = APIRouter(prefix="/v1/jobs", tags=["jobs"])
_POLL_S = 0.5  # how often a socket looks at the row when its own replica sends nothing
MAX_OFFSET = 1_000_000_000  # far past any job table; keeps the value inside a 64-bit SQL integer


class JobProgress(BaseModel):
    fraction: float
    stage: str


class JobInput(BaseModel):
    name: str
    filename: str | None = None
    size: int | None = None


class JobOut(BaseModel):
    id: str
    kind: str
    created_by: str = Field(description="the id of the key that created the job ('admin': the service's own keys)")
    state: Literal["queued", "running", "succeeded", "failed", "cancelled"]
    progress: JobProgress
    params: dict[str, Any]
    inputs: list[JobInput]
    result: dict[str, Any] | None
    error: str | None
    attempts: int = Field(description="Attempts begun: lost workers + service restarts + the open or final one.")
    worker_losses: int = Field(description="Attempts whose worker or node was lost; the job fails once they "
                                           "reach SWEEPCAST_JOB_MAX_ATTEMPTS.")
    service_restarts: int = Field(description="Attempts cut short because the service stopped or died; they "
                                              "never count against SWEEPCAST_JOB_MAX_ATTEMPTS.")
    created_at: dt.datetime
    started_at: dt.datetime | None
    finished_at: dt.datetime | None
    updated_at: dt.datetime


class JobList(BaseModel):
    jobs: list[JobOut]
    limit: int
    offset: int


def job_accepted(job: Any) -> JSONResponse:
    """202 with the new job and its Location, as every route that starts a job answers."""
    body = JobOut.model_validate(job_public(job)).model_dump(mode="json")
    return JSONResponse(body, 202, headers={"Location": f"/v1/jobs/{job.id}"})


async def load_job(job_id: str, svc: Services, who: Principal) -> Job:
    """The job, when ``who`` may see it; 404 otherwise, the same as for a job that does not exist."""
    job = await asyncio.to_thread(svc.jobs.get, job_id)
    if job is None or not who.owns(job.created_by):
        raise ApiError(404, f"no job with id {job_id!r}", "job_not_found")
    return job


@router.get("", response_model=JobList, summary="List jobs, newest first",
            description="The key's own jobs (an admin key: every key's).")
async def list_jobs(
    state: Literal["queued", "running", "succeeded", "failed", "cancelled"] | None = None,
    kind: str | None = Query(None, max_length=100),
    limit: int = Query(50, ge=1, le=500),
    offset: int = Query(0, ge=0, le=MAX_OFFSET),
    svc: Services = Depends(services),
    who: Principal = Depends(principal),
) -> dict[str, Any]:
    rows = await asyncio.to_thread(svc.jobs.list, state, kind, limit, offset, None if who.is_admin else who.id)
    return {"jobs": [job_public(j) for j in rows], "limit": limit, "offset": offset}


@router.get("/{job_id}", response_model=JobOut, summary="One job: state, progress, result manifest or error")
async def get_job(job_id: str, svc: Services = Depends(services), who: Principal = Depends(principal)) -> dict[str, Any]:
    return job_public(await load_job(job_id, svc, who))


@router.get("/{job_id}/results/{name:path}", summary="Download one result file of a succeeded job",
            response_class=Response, responses={200: {"content": {"application/octet-stream": {}}},
                                                409: {"description": "the job has not succeeded (it has no results)"},
                                                410: {"description": "the result was listed but is no longer stored"}})
async def get_result(job_id: str, name: str, svc: Services = Depends(services),
                     who: Principal = Depends(principal)) -> StreamingResponse:
    job = await load_job(job_id, svc, who)
    if job.state != JobState.succeeded.value:
        raise ApiError(409, f"job {job_id} has no results: it is {job.state}", "job_not_succeeded")
    files = {f["name"]: f for f in (job.result or {}).get("files", [])}
    if name not in files:
        raise ApiError(404, f"job {job_id} has no result named {name!r}; it has: {', '.join(sorted(files))}",
                       "result_not_found")
    try:
        handle = await asyncio.to_thread(svc.store.open, f"{results_prefix(job_id)}/{name}")
    except BlobNotFound:
        raise ApiError(410, f"result {name!r} of job {job_id} is no longer stored", "result_gone") from None

    def chunks() -> Any:
        with handle:
            while chunk := handle.read(1 << 20):
                yield chunk

    filename = name.rsplit("/", 1)[-1]
    return StreamingResponse(
        chunks(), media_type=files[name]["content_type"],
        headers={"Content-Length": str(files[name]["size"]),
                 "Content-Disposition": f'attachment; filename="{filename}"'},
    )


@router.delete("/{job_id}", summary="Cancel an active job, or delete a finished one and its files",
               responses={200: {"model": JobOut, "description": "the job was active and is now cancelled"},
                          204: {"description": "the finished job and its files were deleted"},
                          409: {"description": "the job imported a recording that still exists: delete the "
                                               "recording instead"}})
async def delete_job(job_id: str, svc: Services = Depends(services), who: Principal = Depends(principal)) -> Any:
    job = await load_job(job_id, svc, who)
    if not JobState(job.state).finished:
        if await svc.dispatcher.cancel(job_id):
            return job_public(await load_job(job_id, svc, who))
        job = await load_job(job_id, svc, who)  # it finished meanwhile: fall through to delete
    rig_id = await asyncio.to_thread(rig_of_recording_job, svc.store, job)
    if rig_id is not None:  # its results are the recording: deleting them here would break it
        raise ApiError(409, f"job {job_id} holds recording {job_id} of rig {rig_id}; delete the recording "
                            f"instead (DELETE /v1/rigs/{rig_id}/recordings/{job_id})", "job_holds_recording")
    await delete_job_and_files(svc, job_id)
    return Response(status_code=204)


@ws_router.websocket("/{job_id}/events")
async def job_events(websocket: WebSocket, job_id: str) -> None:
    """Progress events as JSON text messages, then ``{"type": "final", "job": ...}``, then close."""
    who = await socket_principal(websocket)
    if who is None:
        await websocket.close(code=1008, reason="missing or wrong API key")
        return
    svc: Services = websocket.app.state.services
    queue = svc.hub.subscribe(job_id)
    try:
        job = await asyncio.to_thread(svc.jobs.get, job_id)
        await websocket.accept()
        if job is None or not who.owns(job.created_by):  # another key's job is no job
            await websocket.send_json({"type": "error", "detail": f"no job with id {job_id!r}"})
            await websocket.close(code=1008, reason="unknown job")
            return
        public = job_public(job)
        if JobState(job.state).finished:
            await websocket.send_json({"type": "final", "job_id": job_id, "job": _jsonable(public)})
            await websocket.close()
            return
        await websocket.send_json({"type": "snapshot", "job_id": job_id, "state": job.state,
                                   "fraction": job.progress, "stage": job.stage, "attempts": job.attempts})
        seen = (job.state, job.progress, job.stage)
        while True:
            try:
                event = await asyncio.wait_for(queue.get(), timeout=_POLL_S)
            except asyncio.TimeoutError:
                # Nothing from this replica's dispatcher: the job may be followed by another replica
                # (or finished there). The row is the shared truth; relay what changed in it.
                job = await asyncio.to_thread(svc.jobs.get, job_id)
                if job is None or JobState(job.state).finished:
                    event = {"type": "final", "job_id": job_id, "job": job_public(job) if job else None}
                elif (job.state, job.progress, job.stage) != seen:
                    seen = (job.state, job.progress, job.stage)
                    event = {"type": "progress", "job_id": job_id, "state": job.state, "fraction": job.progress,
                             "stage": job.stage, "attempt": job.attempts, "source": "table"}
                else:
                    continue
            if event.get("type") == "progress":
                seen = (event.get("state", "running"), event["fraction"], event["stage"])
            await websocket.send_json(_jsonable(event))
            if event.get("type") == "final":
                await websocket.close()
                return
    except WebSocketDisconnect:
        pass
    finally:
        svc.hub.unsubscribe(job_id, queue)


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_jsonable(v) for v in value]
    if isinstance(value, dt.datetime):
        return value.isoformat()
    return value
