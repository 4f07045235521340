"""Recordings of a rig (uploaded videos or image folders, imported by a job) and batch renders over them.

A thin adapter: uploads are checked by the recording code (:mod:`workers.streaming.recording`), the
import and the render are the streaming engine's jobs (:mod:`workers.streaming.job`).
"""
from __future__ import annotations

import asyncio
from typing import Any, Literal

from fastapi import APIRouter, Depends, File, Query, Request, UploadFile
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, Field

from app.auth import principal, require_key
from app.keys import Principal
from app.errors import ApiError
from app.limits import BATCH_BODY
from app.frame_atlases import AtlasKey, build_atlas
from app.stored_rigs import (delete_recording_data, load_rig, recording_or_404, recording_views, require_ready,
                            rig_json_bytes, rig_meta_or_404, view_limits)
from app.routers.jobs import JobOut, job_accepted
from app.params_form import params_form
from app.services import Services, Upload, create_job, run_compute, services
from workers.streaming import actor
from workers.streaming.browser import ATLAS_FORMATS
from workers.streaming.session import MAX_SOURCE_FACTOR
from workers.streaming import store as rigstore
from workers.streaming.job import RECORDING_JOB, RENDER_JOB
from workers.streaming.params import (ARCHIVE_INPUT, BatchRenderParams, RecordingImportParams, RecordingRequest,
                                      background_input, media_input)
from workers.streaming.recording import (check_archive_upload, check_background_uploads, check_video_uploads,
                                         match_cameras)

router = APIRouter(prefix="/v1/rigs", tags=["rigs"], dependencies=[Depends(require_key)])


class Progress(BaseModel):
    fraction: float
    stage: str


class RecordingOut(BaseModel):
    id: str
    rig_id: str
    name: str | None
    kind: Literal["upload", "demo"] | None
    created_at: str | None
    state: Literal["processing", "ready", "failed", "gone"]
    progress: Progress
    job_id: str | None
    frames: int | None = Field(None, description="frames per camera (when ready)")
    fps: float | None = None
    background: Literal["given", "median"] | None = None
    error: str | None = None


class RecordingList(BaseModel):
    recordings: list[RecordingOut]


@router.post("/{rig_id}/recordings", status_code=202, response_model=RecordingOut, openapi_extra=BATCH_BODY, responses={403: {"description": "the rig is the demo rig, which only an admin key may change"}},
             summary="Add a recording: one video per camera, or a zip of per-camera image folders",
             description="Videos are matched to cameras by file name (the camera's name), else by order. "
                         "A zip holds `<camera name>/<images in name order>` and optionally "
                         "`backgrounds/<camera name>.png`. Frame counts, sizes and rates are checked against "
                         "the rig at once (422); a job then decodes and stores the frames (state `processing`, "
                         "then `ready`). Backgrounds (empty-scene images, one per camera) give the silhouettes; "
                         "without them each camera's temporal median is used.")
async def create_recording(
    rig_id: str,
    videos: list[UploadFile] | None = File(None, description="one video per camera, synchronised by frame index"),
    archive: UploadFile | None = File(None, description="a zip of per-camera image folders"),
    backgrounds: list[UploadFile] | None = File(None, description="optional empty-scene image per camera"),
    req: RecordingRequest = params_form(RecordingRequest, " (name, fps of image folders)"),
    svc: Services = Depends(services),
    who: Principal = Depends(principal),
) -> JSONResponse:
    await rig_meta_or_404(svc, rig_id, who, change=True)
    rig = await load_rig(svc, rig_id)
    if (videos is None) == (archive is None):
        raise ApiError(422, "send either 'videos' (one per camera) or 'archive' (a zip of image folders)",
                       "invalid_request")
    media = videos or [archive]
    if len(media) + len(backgrounds or []) > svc.settings.max_batch_files:
        raise ApiError(422, f"too many files; the limit is {svc.settings.max_batch_files}", "invalid_request")
    # the engine's checks; a RecordingError is a 422 invalid_recording
    if videos is not None:
        cameras = match_cameras([v.filename or "" for v in videos], rig)
        await run_compute(svc, check_video_uploads, [(v.filename or "a video", v.file) for v in videos], cameras,
                          rig, svc.settings.max_recording_frames)
    else:
        cameras = []
        await run_compute(svc, check_archive_upload, archive.file, archive.filename or "the archive", rig,
                          svc.settings.max_recording_frames, svc.settings.zip_limits)
    bg_cameras = match_cameras([b.filename or "" for b in backgrounds], rig, "backgrounds") if backgrounds else []
    if backgrounds:
        await run_compute(svc, check_background_uploads, [(b.filename or "", b.file) for b in backgrounds],
                          bg_cameras, rig)
    job_params = RecordingImportParams(
        rig_id=rig_id, source="videos" if videos is not None else "images", cameras=cameras,
        backgrounds=bg_cameras, fps=req.fps, max_frames=svc.settings.max_recording_frames, name=req.name)
    uploads = [Upload("rig", rig_json_bytes(rig), {"filename": "rig.json"})]
    if videos is not None:
        uploads += [Upload(media_input(i), v.file, {"filename": v.filename}) for i, v in enumerate(videos)]
    else:
        uploads.append(Upload(ARCHIVE_INPUT, archive.file, {"filename": archive.filename}))
    uploads += [Upload(background_input(i), b.file, {"filename": b.filename}) for i, b in enumerate(backgrounds or [])]
    job = await create_job(svc, who, RECORDING_JOB, job_params, uploads)
    meta = await asyncio.to_thread(rigstore.save_recording_meta, svc.store, rig_id, job.id,
                                   {"name": req.name or media[0].filename, "kind": "upload"})
    body = RecordingOut.model_validate(await recording_or_404(svc, rig_id, meta["id"])).model_dump(mode="json")
    return JSONResponse(body, 202, headers={"Location": f"/v1/rigs/{rig_id}/recordings/{meta['id']}"})


@router.get("/{rig_id}/recordings", response_model=RecordingList, summary="The rig's recordings, oldest first")
async def list_recordings(rig_id: str, svc: Services = Depends(services),
                          who: Principal = Depends(principal)) -> dict[str, Any]:
    await rig_meta_or_404(svc, rig_id, who)
    return {"recordings": await recording_views(svc, rig_id)}


@router.get("/{rig_id}/recordings/{recording_id}", response_model=RecordingOut,
            summary="One recording: state (processing, ready, failed), import progress, frames, rate")
async def get_recording(rig_id: str, recording_id: str, svc: Services = Depends(services),
                        who: Principal = Depends(principal)) -> dict[str, Any]:
    await rig_meta_or_404(svc, rig_id, who)
    return await recording_or_404(svc, rig_id, recording_id)


@router.delete("/{rig_id}/recordings/{recording_id}", status_code=204, response_class=Response,
               summary="Delete a recording (its import stops, its session ends)", responses={403: {"description": "the rig is the demo rig, which only an admin key may change"}})
async def delete_recording(rig_id: str, recording_id: str, svc: Services = Depends(services),
                           who: Principal = Depends(principal)) -> Response:
    await rig_meta_or_404(svc, rig_id, who, change=True)
    recording = await recording_or_404(svc, rig_id, recording_id)
    await asyncio.to_thread(actor.end_sessions, rig_id, recording_id)
    await delete_recording_data(svc, rig_id, recording)
    return Response(status_code=204)


@router.get("/{rig_id}/recordings/{recording_id}/frames/{frame}", response_class=Response,
            summary="One frame set of a recording as one image, for viewers that render in their browser",
            description="Every camera's frame `frame` (an index, or `background` for the empty-scene images) in rig "
                        "order, tiled `render.atlas_columns` per row in cells of the largest camera image, shrunk by "
                        "`factor` (the integer source factor of the view size, as the server's renderer uses) and "
                        "undistorted. The URL never changes what it answers: `Cache-Control: immutable` and an "
                        "ETag (`If-None-Match` gets 304) let the browser and proxies keep it. PNG is lossless (the "
                        "viewer's default: its view then matches the server's); JPEG (`quality`) is about 5x "
                        "smaller.",
            responses={200: {"content": {"image/jpeg": {}, "image/png": {}}}, 304: {"description": "not modified"},
                       409: {"description": "the recording is still being imported, or its import failed"}})
async def get_frame_set(
    request: Request, rig_id: str, recording_id: str, frame: str,
    factor: int = Query(1, ge=1, le=MAX_SOURCE_FACTOR, description="integer shrink factor of every camera image"),
    format: Literal["png", "jpeg"] = Query("png", description="image format of the atlas: png is lossless"),
    quality: int = Query(90, ge=50, le=100, description="JPEG quality"),
    svc: Services = Depends(services),
    who: Principal = Depends(principal),
) -> Response:
    await rig_meta_or_404(svc, rig_id, who)
    recording = await recording_or_404(svc, rig_id, recording_id)
    require_ready(recording)
    if frame != "background" and not (frame.isdigit() and int(frame) < recording["frames"]):
        raise ApiError(404, f"recording {recording_id} has no frame {frame!r}: frames are 0..{recording['frames'] - 1} "
                            f"or 'background'", "frame_not_found")
    key = AtlasKey(recording_id, frame if frame == "background" else int(frame), factor, format,
                   quality if format == "jpeg" else 0)
    headers = {"ETag": key.etag, "Cache-Control": f"{'private' if svc.auth.known_enabled else 'public'}, "
                                                  "max-age=31536000, immutable"}
    if request.headers.get("if-none-match") == key.etag:
        return Response(status_code=304, headers=headers)

    async def encode() -> bytes:  # only when no viewer asked for it before: a cached atlas reads nothing stored
        return await run_compute(svc, build_atlas, svc.store, await load_rig(svc, rig_id), key)

    data = await svc.atlases.get(key, encode)
    return Response(data, media_type=ATLAS_FORMATS[format][1], headers=headers)


# --- batch renders --------------------------------------------------------------------------------
@router.post("/{rig_id}/renders", status_code=202, response_model=JobOut,
             responses={409: {"description": "the recording is still being imported, or its import failed"}},
             summary="Render a camera path over a recording: a job -> H.264 MP4 + zip of depth PNGs",
             description="The path is an `orbit` (azimuth from/to around the rig) or `keyframes` (orbit, "
                         "look_at or pose each); output frame k shows recording frame "
                         "`frame_start + k (frame_end - frame_start) / (frames - 1)`. Results: `video.mp4` and "
                         "`depth.zip` (16-bit PNGs, depth x 1000 = millimetres for a rig in metres, 0 = no surface, "
                         "plus `path.json` with every camera). Progress is reported per frame.")
async def create_render(rig_id: str, params: BatchRenderParams, svc: Services = Depends(services),
                        who: Principal = Depends(principal)) -> JSONResponse:
    await rig_meta_or_404(svc, rig_id, who)
    recording = await recording_or_404(svc, rig_id, params.recording_id)
    require_ready(recording)
    frames = recording["frames"]
    end = params.frame_end if params.frame_end is not None else frames - 1
    if params.frame_start >= frames or end >= frames:
        raise ApiError(422, f"frames {params.frame_start}..{end} are out of range: recording {recording['id']} has "
                            f"{frames} frames (0..{frames - 1})", "invalid_parameters")
    view_limits(svc.settings).check(params.width, params.height, params.planes)
    rig = await load_rig(svc, rig_id)
    job = await create_job(svc, who, RENDER_JOB, params,
                           [Upload("rig", rig_json_bytes(rig), {"filename": "rig.json"})],
                           {"recording": rigstore.archive_key(recording["id"])})
    return job_accepted(job)
