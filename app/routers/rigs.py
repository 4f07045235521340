"""Camera rigs for virtual views: calibrations, recordings, batch renders and the live sessions.

Sockets (live ingest and viewers) are in :mod:`app.routers.rig_sockets`.
"""
from __future__ import annotations

import asyncio
import tempfile
from pathlib import Path
from typing import Any, Literal

from fastapi import APIRouter, Depends, File, Form, UploadFile
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, Field

from app.auth import require_key
from app.errors import ApiError
from app.routers.jobs import JobOut, job_accepted
from app.routers.rig_support import (delete_recording_data, load_rig, recording_or_404,
                                     recording_views, require_ready, rig_json_bytes, rig_meta_or_404, view_limits)
from app.services import Services, Upload, create_job, parse_params, run_compute, services
from app.uploads import check_size
from workers.camera import CameraError
from workers.common.safezip import SafeZip, ZipLimits
from workers.storage import safe_name
from workers.streaming import actor
from workers.streaming import store as rigstore
from workers.streaming.images import image_size
from workers.streaming.job import RECORDING_JOB, RENDER_JOB
from workers.streaming.params import BatchRenderParams, RecordingImportParams, RecordingRequest
from workers.streaming.recording import (RecordingError, check_image_sizes, check_videos, match_cameras,
                                         scan_image_zip)
from workers.streaming.session import ViewError
from workers.streaming.video import VideoError, probe_video
from workers.streaming.viewpoint import orbit_frame
from workers.sweep.rig import Rig, RigError
from workers.sweep.rig_io import (CAMERA_LIST, load_middlebury_par, load_rig as load_rig_file, metres_per_unit,
                                  rig_format, rig_to_dict)

router = APIRouter(prefix="/v1/rigs", tags=["rigs"], dependencies=[Depends(require_key)])
sessions_router = APIRouter(prefix="/v1/sessions", tags=["rigs"], dependencies=[Depends(require_key)])

CALIBRATION_HELP = ("calibration file(s): our rig JSON (.json), a plain camera list (.json: {\"cameras\": [{name, K, "
                    "distCoef, R, t, resolution}]}, as CMU Panoptic's calibration_*.json), OpenCV FileStorage "
                    "(.yml/.yaml/.xml), a Middlebury *_par.txt (give width and height), or COLMAP text (cameras.txt + "
                    "images.txt)")
UNITS_HELP = ("the unit of the calibration's translations t: m, cm, mm, or a positive number of metres per unit "
              "(e.g. 0.0254 for inches); default: cm for a plain camera list (CMU Panoptic's), m for every other "
              "format. The stored rig is in metres.")


class RigSummary(BaseModel):
    id: str
    name: str
    created_at: str
    format: str
    demo: bool = False
    cameras: int


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


class RigOut(RigSummary):
    calibration: dict[str, Any] = Field(description="the rig in our JSON format (cameras with K, R, t, size)")
    orbit: dict[str, Any] = Field(description="the orbit frame viewers start from: target, up, home elevation "
                                              "and distance, each camera's azimuth and elevation (degrees)")
    recordings: list[RecordingOut]


class RigList(BaseModel):
    rigs: list[RigSummary]


class RecordingList(BaseModel):
    recordings: list[RecordingOut]


class SessionOut(BaseModel):
    name: str
    rig_id: str
    source: str
    info: dict[str, Any] | None = Field(None, description="viewers, renders, frames, ... (None: not answering)")


class SessionList(BaseModel):
    sessions: list[SessionOut]


def _summary(meta: dict[str, Any]) -> dict[str, Any]:
    return {"id": meta["id"], "name": meta.get("name") or meta["id"], "created_at": meta["created_at"],
            "format": meta.get("format", "json"), "demo": bool(meta.get("demo")), "cameras": meta["cameras"]}


# --- rigs -----------------------------------------------------------------------------------------
@router.post("", status_code=201, response_model=RigOut, summary="Add a camera rig from its calibration")
async def create_rig(
    files: list[UploadFile] = File(..., description=CALIBRATION_HELP),
    name: str | None = Form(None, max_length=200, description="a name to show (default: the file name)"),
    width: int | None = Form(None, ge=1, le=65535, description="image width (Middlebury *_par.txt only)"),
    height: int | None = Form(None, ge=1, le=65535, description="image height (Middlebury *_par.txt only)"),
    units: str | None = Form(None, max_length=32, description=UNITS_HELP),
    camera_type: str | None = Form(None, max_length=64, description="plain camera list only: keep the cameras "
                                                                    "of this type (e.g. hd of CMU Panoptic's "
                                                                    "vga, hd and kinect-color)"),
    svc: Services = Depends(services),
) -> JSONResponse:
    for f in files:
        check_size(f, svc.settings.max_upload_bytes)
    try:
        metres_per_unit(units, CAMERA_LIST)
    except RigError as exc:
        raise ApiError(422, f"units: {str(exc).split(': ', 2)[-1]}", "invalid_parameters") from None
    contents = [(safe_name(f.filename or "rig.json", "rig.json"), await f.read()) for f in files]
    try:
        rig, fmt = await run_compute(svc, _parse_calibration, contents, width, height, units, camera_type)
    except (RigError, CameraError, ValueError) as exc:
        raise ApiError(422, f"unusable calibration: {exc}", "invalid_rig") from None
    _check_rig(rig, svc)
    rig_id = rigstore.new_rig_id()
    meta = await asyncio.to_thread(rigstore.save_rig, svc.store, rig_id, rig,
                                   {"name": name or contents[0][0], "format": fmt, "demo": False})
    body = RigOut.model_validate(await _rig_out(svc, meta, rig)).model_dump(mode="json")
    return JSONResponse(body, 201, headers={"Location": f"/v1/rigs/{rig_id}"})


def _parse_calibration(contents: list[tuple[str, bytes]], width: int | None, height: int | None,
                       units: str | None = None, camera_type: str | None = None) -> tuple[Rig, str]:
    """The rig of uploaded calibration files (in metres: ``units`` as :func:`metres_per_unit`) and the
    format's name. The readers name the files they read by path: an error shows the client's file
    name, never this temporary folder."""
    with tempfile.TemporaryDirectory(prefix="sweepcast-rig-") as tmp:
        try:
            return _read_calibration(Path(tmp), contents, width, height, units, camera_type)
        except (RigError, CameraError, ValueError) as exc:
            raise ValueError(_without_folder(str(exc), Path(tmp))) from None


def _without_folder(message: str, folder: Path) -> str:
    """``message`` with every path inside ``folder`` shortened to the file's own name."""
    for form in {str(folder), str(folder.resolve())}:
        message = message.replace(form + "/", "").replace(form, "the upload")
    return message


def _read_calibration(folder: Path, contents: list[tuple[str, bytes]], width: int | None,
                      height: int | None, units: str | None = None,
                      camera_type: str | None = None) -> tuple[Rig, str]:
    """Write the files into ``folder`` and read them with the reader their names call for."""
    names = sorted(n for n, _ in contents)
    for filename, data in contents:
        (folder / filename).write_bytes(data)
    if len(contents) > 1:
        if names != ["cameras.txt", "images.txt"]:
            raise ValueError(f"several files are only understood as COLMAP text (cameras.txt + images.txt); "
                             f"got {', '.join(names)}")
        return load_rig_file(folder, units, camera_type), "colmap"
    path = folder / names[0]
    if path.name.endswith("_par.txt"):
        if width is None or height is None:
            raise ValueError("a Middlebury *_par.txt has no image size: give the form fields width and height")
        if camera_type is not None:
            raise ValueError("camera_type: only a plain camera list has camera types")
        return load_middlebury_par(path, width, height).rescaled(metres_per_unit(units, "middlebury")), "middlebury"
    if path.name in ("cameras.txt", "images.txt"):
        raise ValueError("COLMAP text needs both cameras.txt and images.txt")
    fmt = rig_format(path)
    return load_rig_file(path, units, camera_type), fmt


def _check_rig(rig: Rig, svc: Services) -> None:
    if len(rig) > svc.settings.max_rig_cameras:
        raise ApiError(422, f"the rig has {len(rig)} cameras; the limit is {svc.settings.max_rig_cameras}", "invalid_rig")
    for cam in rig.cameras:
        if cam.width * cam.height > svc.settings.max_image_pixels:
            raise ApiError(422, f"camera {cam.name} is {cam.width}x{cam.height}, over the limit of "
                                f"{svc.settings.max_image_pixels:,} pixels", "invalid_rig")


async def _rig_out(svc: Services, meta: dict[str, Any], rig: Rig) -> dict[str, Any]:
    return {**_summary(meta), "calibration": rig_to_dict(rig),
            "orbit": await run_compute(svc, lambda: orbit_frame(rig).to_dict()),
            "recordings": await recording_views(svc, meta["id"])}


@router.get("", response_model=RigList, summary="List rigs, newest first")
async def list_rigs(svc: Services = Depends(services)) -> dict[str, Any]:
    metas = await asyncio.to_thread(rigstore.list_rig_metas, svc.store)
    return {"rigs": [_summary(m) for m in metas]}


@router.get("/{rig_id}", response_model=RigOut, summary="One rig: calibration, orbit frame, recordings")
async def get_rig(rig_id: str, svc: Services = Depends(services)) -> dict[str, Any]:
    meta = await rig_meta_or_404(svc, rig_id)
    return await _rig_out(svc, meta, await load_rig(svc, rig_id))


@router.delete("/{rig_id}", status_code=204, response_class=Response,
               summary="Delete a rig with its recordings; its sessions end")
async def delete_rig(rig_id: str, svc: Services = Depends(services)) -> Response:
    await rig_meta_or_404(svc, rig_id)
    await asyncio.to_thread(actor.end_sessions, rig_id)
    for recording in await recording_views(svc, rig_id):
        await delete_recording_data(svc, rig_id, recording)
    await asyncio.to_thread(rigstore.delete_rig, svc.store, rig_id)
    return Response(status_code=204)


# --- recordings -----------------------------------------------------------------------------------
@router.post("/{rig_id}/recordings", status_code=202, response_model=RecordingOut,
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
    params: str | None = Form(None, description="JSON object of RecordingRequest (name, fps of image folders)"),
    svc: Services = Depends(services),
) -> JSONResponse:
    req = parse_params(RecordingRequest, params)
    await rig_meta_or_404(svc, rig_id)
    rig = await load_rig(svc, rig_id)
    if (videos is None) == (archive is None):
        raise ApiError(422, "send either 'videos' (one per camera) or 'archive' (a zip of image folders)",
                       "invalid_request")
    media = videos or [archive]
    if len(media) + len(backgrounds or []) > svc.settings.max_batch_files:
        raise ApiError(422, f"too many files; the limit is {svc.settings.max_batch_files}", "invalid_request")
    try:
        if videos is not None:
            cameras = match_cameras([v.filename or "" for v in videos], rig)
            await run_compute(svc, _probe_videos, videos, cameras, rig, svc.settings.max_recording_frames)
        else:
            cameras = []
            await run_compute(svc, _probe_archive, archive, rig, svc.settings.max_recording_frames,
                                    svc.settings.zip_limits)
        bg_cameras = match_cameras([b.filename or "" for b in backgrounds], rig, "backgrounds") if backgrounds else []
        if backgrounds:
            await run_compute(svc, _check_backgrounds, backgrounds, bg_cameras, rig)
    except RecordingError as exc:
        raise ApiError(422, str(exc), "invalid_recording") from None
    job_params = RecordingImportParams(
        rig_id=rig_id, source="videos" if videos is not None else "images", cameras=cameras,
        backgrounds=bg_cameras, fps=req.fps, max_frames=svc.settings.max_recording_frames, name=req.name)
    uploads = [Upload("rig", rig_json_bytes(rig), {"filename": "rig.json"})]
    if videos is not None:
        uploads += [Upload(f"media-{i:03d}", v.file, {"filename": v.filename}) for i, v in enumerate(videos)]
    else:
        uploads.append(Upload("archive", archive.file, {"filename": archive.filename}))
    uploads += [Upload(f"background-{i:03d}", b.file, {"filename": b.filename}) for i, b in enumerate(backgrounds or [])]
    job = await create_job(svc, RECORDING_JOB, job_params, uploads)
    meta = await asyncio.to_thread(rigstore.save_recording_meta, svc.store, rig_id, job.id,
                                   {"name": req.name or media[0].filename, "kind": "upload"})
    body = RecordingOut.model_validate(await recording_or_404(svc, rig_id, meta["id"])).model_dump(mode="json")
    return JSONResponse(body, 202, headers={"Location": f"/v1/rigs/{rig_id}/recordings/{meta['id']}"})


def _probe_videos(videos: list[UploadFile], cameras: list[int], rig: Rig, max_frames: int) -> None:
    infos = []
    for v in videos:
        try:
            infos.append((v.filename or "video", probe_video(v.file)))
        except VideoError as exc:
            raise RecordingError(f"{v.filename or 'a video'} {exc}") from None
        finally:
            v.file.seek(0)
    check_videos(infos, cameras, rig, max_frames)


def _probe_archive(archive: UploadFile, rig: Rig, max_frames: int, limits: ZipLimits) -> None:
    """Check the archive's structure (SafeZip: member count, sizes, ratio, names) and its layout
    against the rig before a job is made of it."""
    try:
        with SafeZip(archive.file, limits, archive.filename or "the archive", RecordingError) as zf:
            check_image_sizes(zf.zipfile, scan_image_zip(zf.zipfile, rig, max_frames), rig)
    finally:
        archive.file.seek(0)


def _check_backgrounds(backgrounds: list[UploadFile], cameras: list[int], rig: Rig) -> None:
    if sorted(cameras) != list(range(len(rig))):
        raise RecordingError(f"give one background image per camera ({len(rig)}) or none")
    for b, c in zip(backgrounds, cameras):
        size = image_size(b.file.read(1 << 16))
        b.file.seek(0)
        cam = rig[c]
        if size != (cam.width, cam.height):
            found = "not a JPEG or PNG" if size is None else f"{size[0]}x{size[1]}"
            raise RecordingError(f"background {b.filename} (camera {cam.name}) is {found}; "
                                 f"the calibration says {cam.width}x{cam.height}")


@router.get("/{rig_id}/recordings", response_model=RecordingList, summary="The rig's recordings, oldest first")
async def list_recordings(rig_id: str, svc: Services = Depends(services)) -> dict[str, Any]:
    await rig_meta_or_404(svc, rig_id)
    return {"recordings": await recording_views(svc, rig_id)}


@router.get("/{rig_id}/recordings/{recording_id}", response_model=RecordingOut,
            summary="One recording: state (processing, ready, failed), import progress, frames, rate")
async def get_recording(rig_id: str, recording_id: str, svc: Services = Depends(services)) -> dict[str, Any]:
    await rig_meta_or_404(svc, rig_id)
    return await recording_or_404(svc, rig_id, recording_id)


@router.delete("/{rig_id}/recordings/{recording_id}", status_code=204, response_class=Response,
               summary="Delete a recording (its import stops, its session ends)")
async def delete_recording(rig_id: str, recording_id: str, svc: Services = Depends(services)) -> Response:
    await rig_meta_or_404(svc, rig_id)
    recording = await recording_or_404(svc, rig_id, recording_id)
    await asyncio.to_thread(actor.end_sessions, rig_id, recording_id)
    await delete_recording_data(svc, rig_id, recording)
    return Response(status_code=204)


# --- batch renders --------------------------------------------------------------------------------
@router.post("/{rig_id}/renders", status_code=202, response_model=JobOut,
             summary="Render a camera path over a recording: a job -> H.264 MP4 + zip of depth PNGs",
             description="The path is an `orbit` (azimuth from/to around the rig) or `keyframes` (orbit, "
                         "look_at or pose each); output frame k shows recording frame "
                         "`frame_start + k (frame_end - frame_start) / (frames - 1)`. Results: `video.mp4` and "
                         "`depth.zip` (16-bit PNGs, depth x 1000 = millimetres for a rig in metres, 0 = no surface, "
                         "plus `path.json` with every camera). Progress is reported per frame.")
async def create_render(rig_id: str, params: BatchRenderParams, svc: Services = Depends(services)) -> JSONResponse:
    await rig_meta_or_404(svc, rig_id)
    recording = await recording_or_404(svc, rig_id, params.recording_id)
    require_ready(recording)
    frames = recording["frames"]
    end = params.frame_end if params.frame_end is not None else frames - 1
    if params.frame_start >= frames or end >= frames:
        raise ApiError(422, f"frames {params.frame_start}..{end} are out of range: recording {recording['id']} has "
                            f"{frames} frames (0..{frames - 1})", "invalid_parameters")
    try:
        view_limits(svc.settings).check(params.width, params.height, params.planes)
    except ViewError as exc:
        raise ApiError(422, exc.detail, "invalid_parameters") from None
    rig = await load_rig(svc, rig_id)
    job = await create_job(svc, RENDER_JOB, params,
                           [Upload("rig", rig_json_bytes(rig), {"filename": "rig.json"})],
                           {"recording": rigstore.archive_key(recording["id"])})
    return job_accepted(job)


# --- sessions -------------------------------------------------------------------------------------
@sessions_router.get("", response_model=SessionList, summary="The virtual-view sessions alive in the cluster")
async def list_sessions(svc: Services = Depends(services)) -> dict[str, Any]:
    found = await asyncio.to_thread(actor.list_sessions)
    infos = await asyncio.gather(*[asyncio.to_thread(actor.session_info, s["name"]) for s in found])
    return {"sessions": [{**s, "info": info} for s, info in zip(found, infos)]}
