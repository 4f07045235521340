"""The review queue of a photo batch: the photos the engine left for a person, and what that person decides.

``/review/{job id}`` serves the page (``app/static/review/``, like the viewer: not under ``/v1``, the page sends the
API key it is given); its data comes from ``/v1/photos/batches/{job id}/review`` and its thumbnails from
``/v1/photos/batches/{job id}/photos/{index}/thumbnail``, made from the uploaded photo when the page asks for one (the
batch itself makes none: most photos left for a person are never looked at, and a thumbnail costs about a fifth of what
analysing a photo does). A decision is written with the engine's lossless writers into a new
fixed file of the job and recorded in its ``report.json`` as a person's decision.
"""
from __future__ import annotations

import asyncio
import datetime as dt
import json
import mimetypes
import threading
from pathlib import Path
from typing import Any, Literal

from fastapi import APIRouter, Depends
from fastapi import Path as PathParam
from fastapi.responses import FileResponse, Response
from pydantic import BaseModel, Field

from app.auth import principal, require_key
from app.keys import Principal
from app.errors import ApiError
from app.jobstore import JobState
from app.routers.jobs import load_job
from app.services import Services, run_compute, services
from workers.common.errors import InputError
from workers.orientation.job import BATCH_JOB, batch_input_name, fixed_name, record_review, summary_of
from workers.orientation.review import ReviewChoice, needs_review, thumbnail, write_choice
from workers.runtime import results_prefix

PAGE = Path(__file__).resolve().parents[1] / "static" / "review"
REPORT = "report.json"
MAX_INDEX = 1_000_000
"""Largest photo index a request may name (far past any batch; keeps the value a small integer)."""

router = APIRouter(prefix="/v1/photos/batches", tags=["photos"], dependencies=[Depends(require_key)])
page_router = APIRouter()
_locks: dict[str, threading.Lock] = {}
_locks_guard = threading.Lock()


class ReviewDecision(BaseModel):
    """A person's decision on one photo, as recorded in the job's report."""

    decided_by: Literal["person"]
    reviewer: str
    at: str = Field(description="when (UTC, ISO 8601)")
    rotation_degrees: int | None = Field(description="the turn chosen; null: left as it is")
    action: Literal["written", "left_as_is"]
    orientation: int | None = Field(description="the Orientation value written (1-8)")
    target: Literal["exif-ifd0", "png-exif", "xmp-sidecar", "none"]
    fixed_file: str | None = Field(description="the job's result file written (the photo or its sidecar)")


class ReviewItem(BaseModel):
    """One photo that needs a person."""

    index: int
    filename: str
    thumbnail: str = Field(description="the photo's thumbnail (GET, with the API key): its stored pixels, EXIF "
                                       "ignored, at most 320 px long")
    reason: str | None = Field(description="why the engine left it: no_cue, conflicting_rotations, low_confidence, "
                                           "or conflicting_metadata (the file's own orientations disagree)")
    message: str = Field(description="the engine's own words")
    engine_rotation_degrees: int | None = Field(description="the turn the engine decided, if it decided one")
    accepted_rotations: list[int] = Field(description="the views in which faces were accepted")
    text_rotation_degrees: int | None = Field(description="the turn the text cue pointed to, if any")
    existing_orientation: int | None
    review: ReviewDecision | None = Field(description="a person's decision, once made")


class ReviewQueue(BaseModel):
    job_id: str
    photos: int = Field(description="photos in the batch")
    items: list[ReviewItem]
    reviewed: int


def _lock(job_id: str) -> threading.Lock:
    with _locks_guard:
        return _locks.setdefault(job_id, threading.Lock())


async def _batch(job_id: str, svc: Services, who: Principal) -> Any:
    job = await load_job(job_id, svc, who)
    if job.kind != BATCH_JOB.name:
        raise ApiError(404, f"job {job_id} is not a photo batch (it is {job.kind})", "not_a_photo_batch")
    if job.state != JobState.succeeded.value:
        raise ApiError(409, f"job {job_id} has nothing to review yet: it is {job.state}", "job_not_succeeded")
    return job


def _entries(svc: Services, job_id: str) -> list[dict[str, Any]]:
    return json.loads(svc.store.read(f"{results_prefix(job_id)}/{REPORT}"))


def _item(job_id: str, entry: dict[str, Any]) -> ReviewItem:
    report = entry["report"]
    reason = report.get("reject_reason") or ("conflicting_metadata" if report.get("conflicts") else None)
    return ReviewItem(index=entry["index"], filename=entry["filename"], reason=reason,
                      thumbnail=f"/v1/photos/batches/{job_id}/photos/{entry['index']}/thumbnail",
                      message=report.get("message", ""), engine_rotation_degrees=report.get("rotation_degrees"),
                      accepted_rotations=report.get("accepted_rotations", []),
                      text_rotation_degrees=(report.get("text") or {}).get("rotation_degrees"),
                      existing_orientation=report.get("existing_orientation"), review=entry.get("review"))


@router.get("/{job_id}/review", response_model=ReviewQueue,
            responses={409: {"description": "the batch has not succeeded (yet)"}},
            summary="The photos of a finished batch that need a person (rejected, or orientations that conflict), "
                    "with the engine's reasons and any decision already made")
async def review_queue(job_id: str, svc: Services = Depends(services),
                       who: Principal = Depends(principal)) -> ReviewQueue:
    await _batch(job_id, svc, who)
    entries = await asyncio.to_thread(_entries, svc, job_id)
    items = [_item(job_id, e) for e in entries if needs_review(e.get("report"))]
    return ReviewQueue(job_id=job_id, photos=len(entries), items=items,
                       reviewed=sum(i.review is not None for i in items))


@router.post("/{job_id}/review/{index}", response_model=ReviewItem,
             responses={409: {"description": "the batch has not succeeded, the photo is not in its review queue, or "
                                             "the job changed meanwhile"},
                        503: {"description": "metadata_tool_unavailable: writing this photo needs ExifTool (PNG) and "
                                             "this deployment has none"}},
             summary="A person's decision on one photo of the queue: the upright turn (written with the lossless "
                     "writers into a new fixed file of the job, or its XMP sidecar) or null to leave it as it is; "
                     "recorded in report.json as decided by that person")
async def decide_photo(job_id: str, choice: ReviewChoice,
                       index: int = PathParam(ge=0, le=MAX_INDEX, description="the photo's index in the batch"),
                       svc: Services = Depends(services), who: Principal = Depends(principal)) -> ReviewItem:
    job = await _batch(job_id, svc, who)
    mode = "sidecar" if (job.params or {}).get("sidecar") else "file"
    try:
        return await run_compute(svc, _decide, svc, job, index, choice, mode)
    except InputError as exc:  # the engine's status and code, with the photo it came from
        raise exc.about(f"photo {index}") from None


def _decide(svc: Services, job: Any, index: int, choice: ReviewChoice, mode: str) -> ReviewItem:
    """Write the choice and record it (one decision of a job at a time: report.json is read, changed, replaced)."""
    with _lock(job.id):
        job = svc.jobs.get(job.id) or job  # the manifest as the last decision left it
        entries = _entries(svc, job.id)
        entry = next((e for e in entries if e["index"] == index), None)
        if entry is None:
            raise ApiError(404, f"batch {job.id} has no photo {index} (it has {len(entries)})", "photo_not_found")
        if not needs_review(entry.get("report")):
            raise ApiError(409, f"photo {index} of batch {job.id} is not in the review queue (the engine decided it"
                                " or could not read it)", "not_for_review")
        written, fixed = None, None
        prefix = results_prefix(job.id)
        if choice.rotation_degrees is not None:
            data = svc.store.read(job.inputs[entry["input"]])
            written = write_choice(data, choice.rotation_degrees, entry["filename"], mode)
            fixed = fixed_name(index, entry["filename"], entry["report"]["format"])
            if written.sidecar is not None:
                fixed += ".xmp"
            svc.store.put(f"{prefix}/{fixed}", written.photo if written.photo is not None else written.sidecar)
        at = dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")
        entries = [record_review(e, choice.rotation_degrees, choice.reviewer.strip(), at, written, fixed)
                   if e["index"] == index else e for e in entries]
        report = json.dumps(entries, indent=2).encode()
        svc.store.put(f"{prefix}/{REPORT}", report)
        result = dict(job.result or {})
        files = {f["name"]: f for f in result.get("files", [])}
        files[REPORT] = {**files.get(REPORT, {"name": REPORT, "content_type": "application/json"}), "size": len(report)}
        if fixed is not None:
            files[fixed] = {"name": fixed, "size": svc.store.size(f"{prefix}/{fixed}"),
                            "content_type": mimetypes.guess_type(fixed)[0] or "application/octet-stream"}
        result.update(files=sorted(files.values(), key=lambda f: f["name"]), summary=summary_of(entries))
        if not svc.jobs.replace_result(job.id, result):
            raise ApiError(409, f"job {job.id} changed while the decision was written", "job_changed")
        return _item(job.id, next(e for e in entries if e["index"] == index))


@router.get("/{job_id}/photos/{index}/thumbnail", response_class=Response,
            responses={200: {"content": {"image/jpeg": {}}, "description": "a JPEG at most 320 px long"},
                       404: {"description": "not a photo batch, or it has no photo with that index"},
                       **{status: {"description": f"the uploaded photo has no picture to show ({why}; its entry in "
                                                  "report.json says so too)"}
                          for status, why in ((400, "empty_file, bad_image"), (413, "too_many_pixels"),
                                              (415, "not_an_image, unsupported_format"), (422, "corrupt_image"))}},
            summary="A small JPEG of one photo of a batch, as the engine analysed it: its stored pixels (EXIF "
                    "ignored), at most 320 px long, in colour where the format allows; made from the upload when "
                    "asked for (the review page asks as a photo scrolls into view)")
async def photo_thumbnail(job_id: str,
                          index: int = PathParam(ge=0, le=MAX_INDEX, description="the photo's index in the batch"),
                          svc: Services = Depends(services), who: Principal = Depends(principal)) -> Response:
    job = await load_job(job_id, svc, who)
    if job.kind != BATCH_JOB.name:
        raise ApiError(404, f"job {job_id} is not a photo batch (it is {job.kind})", "not_a_photo_batch")
    name = batch_input_name(index)
    if name not in job.inputs:
        raise ApiError(404, f"batch {job_id} has no photo {index} (it has {len(job.inputs)})", "photo_not_found")
    filename = str((job.input_meta or {}).get(name, {}).get("filename") or name)
    data = await asyncio.to_thread(svc.store.read, job.inputs[name])
    try:
        small = await run_compute(svc, thumbnail, data, filename, svc.settings.max_image_pixels)
    except InputError as exc:
        raise exc.about(f"photo {index}") from None
    # the upload never changes, so neither does its thumbnail: the page's browser keeps it while the job lasts
    return Response(small, media_type="image/jpeg", headers={"Cache-Control": "private, max-age=86400"})


@page_router.get("/review/{job_id}", include_in_schema=False)
async def review_page(job_id: str) -> FileResponse:
    """The review page (the job id is read by the page from its own address)."""
    return FileResponse(PAGE / "index.html", media_type="text/html")
