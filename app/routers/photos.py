"""Orientation of photos (faces first, then text): detect, write it (the file's tag or an XMP sidecar), or fix
a whole batch as a job. Every format a photo library holds: JPEG, WebP, TIFF, PNG, HEIC/HEIF, AVIF, RAW."""
from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, File, Form, UploadFile
from fastapi.responses import JSONResponse, Response

from app.auth import principal, require_key
from app.keys import Principal
from app.errors import ApiError
from app.limits import BATCH_BODY
from app.routers.jobs import JobOut, job_accepted
from app.services import Services, Upload, create_job, run_compute, services
from app.settings import Settings
from app.uploads import check_size, read_upload
from workers.common.errors import InputError
from workers.common.models import models_dir
from workers.orientation.detect import detector_config
from workers.orientation.job import BATCH_JOB, OrientationBatchParams, batch_input_name
from workers.orientation.orient import DetectorConfig, OrientationReport, analyze, get_detector, orient_file

_MEDIA = {"jpeg": "image/jpeg", "webp": "image/webp", "tiff": "image/tiff", "png": "image/png"}
"""The media type of each format /orient returns a tagged photo in (its own format)."""
XMP_MEDIA = "application/rdf+xml"
"""The media type of an XMP sidecar."""

router = APIRouter(prefix="/v1/photos", tags=["photos"], dependencies=[Depends(require_key)])


def orientation_config(settings: Settings) -> DetectorConfig:
    """The orientation engine the service uses: YuNet when there is one, the text cue as set (as its jobs do)."""
    return detector_config(settings, models_dir(settings.data_dir))


def _detector(svc: Services) -> Any:
    return get_detector(orientation_config(svc.settings))


@router.post("/orientation", response_model=OrientationReport,
             responses={415: {"description": "the file is not an image, or not a format this route reads"},
                        503: {"description": "metadata_tool_unavailable: the file needs ExifTool (PNG, a RAW preview) "
                                             "and this deployment has none"}},
             summary="Detect which way is up in a photo: faces first, then text; never a guess. The answer says "
                     "every orientation the file states and what /orient would write where")
async def detect_orientation(file: UploadFile = File(..., description="a JPEG, WebP, TIFF, PNG, HEIC/HEIF, AVIF "
                                                                      "or RAW photo"),
                             sidecar: bool = Form(False, description="plan an XMP sidecar instead of a write into "
                                                                     "the file"),
                             force: bool = Form(False, description="plan to replace an existing orientation other "
                                                                   "than 1"),
                             svc: Services = Depends(services)) -> OrientationReport:
    data = await read_upload(file, svc.settings.max_upload_bytes)
    mode = "sidecar" if sidecar else "file"
    try:
        return await run_compute(svc, lambda: analyze(data, _detector(svc), svc.settings.max_image_pixels,
                                                      file.filename, mode=mode, force=force))
    except InputError as exc:  # the engine's status and code, with the file it came from
        raise exc.about(file.filename) from None


@router.post("/orient", response_class=Response,
             summary="Write a photo's orientation: the same file with its tag set (JPEG, WebP, TIFF: EXIF IFD0; "
                     "PNG: eXIf), or an XMP sidecar (HEIC/HEIF, AVIF, RAW, or sidecar=true)",
             responses={415: {"description": "the file is not a JPEG, WebP, TIFF, PNG, HEIC/HEIF, AVIF or RAW photo"},
                        503: {"description": "metadata_tool_unavailable: the write needs ExifTool (PNG, a sidecar "
                                             "update) and this deployment has none"},
                        200: {"content": {media: {} for media in (*_MEDIA.values(), XMP_MEDIA)},
                              "description": "the photo with its tag set, image data untouched (image/jpeg, "
                                             "image/webp, image/tiff, image/png), or the XMP sidecar to store "
                                             "beside it (application/rdf+xml, Content-Disposition names it: "
                                             "photo.heic.xmp). Headers: X-Orientation (the orientation the "
                                             "photo, with the returned sidecar, carries, 1-8, or 'none'), "
                                             "X-Orientation-Decision (upright, rotated, rejected), "
                                             "X-Orientation-Cue (faces, text, none), X-Orientation-Needs-Review, "
                                             "X-Orientation-Action (written, kept_existing, already_set, "
                                             "not_written_rejected), X-Orientation-Target (exif-ifd0, png-exif, "
                                             "xmp-sidecar, none) and X-Orientation-Conflicts (how many "
                                             "disagreements between the file's orientation sources)"},
                        204: {"description": "the target is a sidecar and there is nothing to write (rejected, "
                                             "kept, or already shown upright); the same X-Orientation headers"}})
async def orient_photo(file: UploadFile = File(..., description="a JPEG, WebP, TIFF, PNG, HEIC/HEIF, AVIF or RAW "
                                                                "photo"),
                       force: bool = Form(False, description="replace an existing orientation other than 1"),
                       sidecar: bool = Form(False, description="return an XMP sidecar instead of the tagged photo "
                                                               "(the photo is then never changed)"),
                       svc: Services = Depends(services)) -> Response:
    data = await read_upload(file, svc.settings.max_upload_bytes)
    mode = "sidecar" if sidecar else "file"
    try:
        outcome = await run_compute(svc, lambda: orient_file(data, _detector(svc), force, svc.settings.max_image_pixels,
                                                             file.filename, mode=mode))
    except InputError as exc:  # the engine's status and code, with the file it came from
        raise exc.about(file.filename) from None
    report = outcome.report
    carried = report.written_orientation if report.written else report.file_orientation
    headers = {
        "X-Orientation": str(carried) if carried is not None else "none",
        "X-Orientation-Decision": report.decision,
        "X-Orientation-Cue": report.cue,
        "X-Orientation-Needs-Review": "true" if report.needs_review else "false",
        "X-Orientation-Action": report.action,
        "X-Orientation-Target": report.write.target if report.write else "none",
        "X-Orientation-Conflicts": str(len(report.conflicts)),
    }
    if outcome.sidecar is not None:
        headers["Content-Disposition"] = f'attachment; filename="{_header_safe(outcome.sidecar_name or "photo.xmp")}"'
        return Response(outcome.sidecar, media_type=XMP_MEDIA, headers=headers)
    if report.format not in _MEDIA or mode == "sidecar":
        return Response(status_code=204, headers=headers)
    return Response(outcome.photo if outcome.photo is not None else data, media_type=_MEDIA[report.format],
                    headers=headers)


def _header_safe(name: str) -> str:
    """A file name fit for a quoted Content-Disposition value (ASCII, no quotes or backslashes)."""
    return "".join(c if 32 <= ord(c) < 127 and c not in '"\\' else "_" for c in name)


@router.post("/batches", status_code=202, response_model=JobOut, openapi_extra=BATCH_BODY,
             summary="Fix many photos in one upload: a job with a report per photo and the fixed files")
async def create_batch(files: list[UploadFile] = File(..., description="the photos (repeat the field)"),
                       force: bool = Form(False, description="replace existing tags other than 1"),
                       sidecar: bool = Form(False, description="XMP sidecars for every photo instead of changed "
                                                               "photos"),
                       text: bool = Form(True, description="when the faces decide nothing, try the text cue "
                                                           "(where the service has it on); false: faces only, "
                                                           "0.1-0.6 s of CPU less per photo without a face"),
                       svc: Services = Depends(services), who: Principal = Depends(principal)) -> JSONResponse:
    limit = svc.settings.max_batch_files
    if len(files) > limit:
        raise ApiError(413, f"{len(files)} files in one batch; the limit is {limit}", "too_many_files")
    for f in files:
        check_size(f, svc.settings.max_upload_bytes)
    uploads = [
        Upload(batch_input_name(i), f.file,
               {"filename": f.filename or batch_input_name(i), "content_type": f.content_type})
        for i, f in enumerate(files)
    ]
    return job_accepted(await create_job(svc, who, BATCH_JOB, OrientationBatchParams(force=force, sidecar=sidecar, text=text), uploads))
