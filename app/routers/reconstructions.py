"""Drone-video 3D reconstruction: a job per video (or zip of ordered stills)."""
from __future__ import annotations

from fastapi import APIRouter, Depends, File, UploadFile
from fastapi.responses import JSONResponse

from app.auth import principal, require_key
from app.keys import Principal
from app.errors import ApiError
from app.limits import BATCH_BODY
from app.routers.jobs import JobOut, job_accepted
from app.params_form import params_form
from app.services import Services, Upload, create_job, services
from app.uploads import check_size
from workers.drone.job import RECONSTRUCT_JOB
from workers.drone.params import ReconstructionParams

router = APIRouter(prefix="/v1/reconstructions", tags=["reconstructions"], dependencies=[Depends(require_key)])


@router.post("", status_code=202, response_model=JobOut, openapi_extra=BATCH_BODY,
             summary="Reconstruct cameras, a point cloud and (for a georeferenced flight) a map from a drone video "
                     "or a zip of ordered images",
             description="A job with progress per stage and counts (a video: decode, track k/N, initialise, BA "
                         "iteration i; stills with GPS, a survey of any size: track k/N photos, match k/N pairs, "
                         "submodels k/N, merge; then georeference; with a dense pass or map products: dense depth "
                         "k/N, surface model k/N tiles, orthophoto k/N tiles). The stages' work runs as tasks across "
                         "the Ray cluster, and an attempt after a lost worker resumes from the finished stages. "
                         "Every registered photo is in the dense cloud and the map; report.json -> mapping says the "
                         "ground resolution chosen and why, and the share of the photos' footprints covered. "
                         "No intrinsics needed: without them the camera is "
                         "self-calibrated (focal length from EXIF or DJI telemetry, else a 72 degree field of view; "
                         "radial distortion refined). Stills with EXIF GPS, or a DJI video with its .SRT telemetry "
                         "(uploaded as 'telemetry' or in the video's subtitle stream), are placed in the local UTM "
                         "zone. Results: points.ply, cameras.txt, images.txt, points3D.txt (COLMAP text), "
                         "trajectory.json, report.json, preview.png; with `\"dense\": true` also dense.ply and "
                         "depth.zip; georeferenced also points.laz; for a georeferenced flight (or with "
                         '`"orthophoto"`/`"dsm"` true) orthophoto.tif (Cloud-Optimized GeoTIFF, RGBA), '
                         "orthophoto.png, dsm.tif (float32 heights) and dsm.png.")
async def create_reconstruction(
    media: UploadFile = File(..., description="a video (MP4, MOV, MKV, AVI, ...) or a zip of ordered images"),
    calibration: UploadFile | None = File(None, description="calibration file (OpenCV YAML/XML/JSON, COLMAP "
                                                            "cameras.txt, or 'fx fy cx cy')"),
    telemetry: UploadFile | None = File(None, description="the video's DJI .SRT telemetry file (GPS per frame)"),
    p: ReconstructionParams = params_form(ReconstructionParams, ', e.g. {"orthophoto": true, "gsd_cm": 5} or '
                                                                '{"fx": 702, "fy": 702, "cx": 600, "cy": 450}'),
    svc: Services = Depends(services),
    who: Principal = Depends(principal),
) -> JSONResponse:
    if media.size == 0:
        raise ApiError(400, f"{media.filename or 'media'} is empty", "empty_file")
    uploads = [Upload("media", media.file, {"filename": media.filename, "content_type": media.content_type})]
    for name, extra in (("calibration", calibration), ("telemetry", telemetry)):
        if extra is not None:
            check_size(extra, svc.settings.max_upload_bytes)
            uploads.append(Upload(name, extra.file, {"filename": extra.filename}))
    return job_accepted(await create_job(svc, who, RECONSTRUCT_JOB, p, uploads))
