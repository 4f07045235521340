"""EXIF orientation of photos (faces first, then text): detect, write the tag, or fix a whole batch as a job."""
from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, File, Form, UploadFile
from fastapi.responses import JSONResponse, Response

from app.auth import require_key
from app.errors import ApiError
from app.routers.jobs import JobOut, job_accepted
from app.services import Services, Upload, create_job, run_compute, services
from app.settings import Settings
from app.uploads import check_size, read_upload
from workers.orientation import errors
from workers.orientation.service import DetectorConfig, OrientationReport, analyze, get_detector, orient_jpeg

router = APIRouter(prefix="/v1/photos", tags=["photos"], dependencies=[Depends(require_key)])

_STATUS = {
    errors.EmptyFile: 400,
    errors.NotAnImage: 415,
    errors.UnsupportedFormat: 415,
    errors.TooManyPixels: 413,
    errors.TruncatedImage: 422,
    errors.CorruptImage: 422,
    errors.UnwritableExif: 422,
}


def orientation_config(settings: Settings) -> DetectorConfig:
    """The orientation engine the service uses: YuNet when there is one, the text cue as set."""
    return DetectorConfig(yunet_model=settings.resolved_yunet_model, text=settings.orientation_text,
                          tesseract=settings.orientation_tesseract)


def _detector(svc: Services) -> Any:
    return get_detector(orientation_config(svc.settings))


def _as_api_error(exc: errors.OrientationInputError, filename: str | None) -> ApiError:
    status = next((s for cls, s in _STATUS.items() if isinstance(exc, cls)), 400)
    name = f"{filename}: " if filename else ""
    return ApiError(status, f"{name}{exc}", exc.code)


@router.post("/orientation", response_model=OrientationReport,
             summary="Detect which way is up in a photo: faces first, then text; never a guess "
                     "(stored pixels; the EXIF tag is ignored)")
async def detect_orientation(file: UploadFile = File(..., description="a JPEG, PNG or WebP photo"),
                             svc: Services = Depends(services)) -> OrientationReport:
    data = await read_upload(file, svc.settings.max_upload_bytes)
    try:
        return await run_compute(svc, lambda: analyze(data, _detector(svc), svc.settings.max_image_pixels))
    except errors.OrientationInputError as exc:
        raise _as_api_error(exc, file.filename) from None


@router.post("/orient", response_class=Response,
             summary="Return the same JPEG with its EXIF Orientation tag set (image data untouched)",
             responses={200: {"content": {"image/jpeg": {}},
                              "description": "the JPEG; headers X-Orientation (the tag the returned file carries, 1-8, "
                                             "or 'none' when it has none or an invalid one), X-Orientation-Decision "
                                             "(upright, rotated, rejected), X-Orientation-Cue (faces, text, "
                                             "none), X-Orientation-Needs-Review (true on a rejection) and "
                                             "X-Orientation-Action (written, kept_existing, already_set, "
                                             "not_written_rejected)"}})
async def orient_photo(file: UploadFile = File(..., description="a JPEG (or WebP) photo"),
                       force: bool = Form(False, description="replace an existing tag other than 1"),
                       svc: Services = Depends(services)) -> Response:
    data = await read_upload(file, svc.settings.max_upload_bytes)
    try:
        new_bytes, report = await run_compute(
            svc, lambda: orient_jpeg(data, _detector(svc), force, svc.settings.max_image_pixels))
    except errors.OrientationInputError as exc:
        raise _as_api_error(exc, file.filename) from None
    media = "image/webp" if new_bytes[:4] == b"RIFF" else "image/jpeg"
    return Response(new_bytes, media_type=media, headers={
        # The tag the returned file carries ("none" when it has no Orientation tag), and the decision.
        "X-Orientation": str(report.file_orientation) if report.file_orientation is not None else "none",
        "X-Orientation-Decision": report.decision,
        "X-Orientation-Cue": report.cue,
        "X-Orientation-Needs-Review": "true" if report.needs_review else "false",
        "X-Orientation-Action": report.action,
    })


@router.post("/batches", status_code=202, response_model=JobOut,
             summary="Fix many photos in one upload: a job with a report per photo and the fixed files")
async def create_batch(files: list[UploadFile] = File(..., description="the photos (repeat the field)"),
                       force: bool = Form(False, description="replace existing tags other than 1"),
                       svc: Services = Depends(services)) -> JSONResponse:
    limit = svc.settings.max_batch_files
    if len(files) > limit:
        raise ApiError(413, f"{len(files)} files in one batch; the limit is {limit}", "too_many_files")
    for f in files:
        check_size(f, svc.settings.max_upload_bytes)
    uploads = [
        Upload(f"photo-{i:04d}", f.file, {"filename": f.filename or f"photo-{i:04d}", "content_type": f.content_type})
        for i, f in enumerate(files)
    ]
    return job_accepted(await create_job(svc, "orientation.batch", {"force": force}, uploads))
