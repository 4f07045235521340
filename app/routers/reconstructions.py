"""Drone-video 3D reconstruction: a job per video (or zip of ordered stills)."""
from __future__ import annotations

from fastapi import APIRouter, Depends, File, Form, UploadFile
from fastapi.responses import JSONResponse

from app.auth import require_key
from app.errors import ApiError
from app.routers.jobs import JobOut, job_accepted
from app.services import Services, Upload, create_job, parse_params, services
from app.uploads import check_size
from workers.drone.job import RECONSTRUCT_JOB
from workers.drone.params import ReconstructionParams

router = APIRouter(prefix="/v1/reconstructions", tags=["reconstructions"], dependencies=[Depends(require_key)])


@router.post("", status_code=202, response_model=JobOut,
             summary="Reconstruct cameras and a point cloud from a drone video or a zip of ordered images",
             description="A job with progress per stage (decode, track k/N, initialise, BA iteration i; with "
                         "dense: dense depth k/M, dense fusion). Results: points.ply, cameras.txt, images.txt, "
                         "points3D.txt (COLMAP text), trajectory.json, report.json, preview.png; with "
                         '`"dense": true` also dense.ply (points, normals, colours) and depth.zip (16-bit depth '
                         "PNGs, scales in report.json under dense); the dense_* parameters tune that pass.")
async def create_reconstruction(
    media: UploadFile = File(..., description="a video (MP4, MOV, MKV, AVI, ...) or a zip of ordered images"),
    calibration: UploadFile | None = File(None, description="calibration file (OpenCV YAML/XML/JSON, COLMAP "
                                                            "cameras.txt, or 'fx fy cx cy')"),
    params: str | None = Form(None, description='JSON object of ReconstructionParams, e.g. {"fx": 702, "fy": 702, '
                                                '"cx": 600, "cy": 450}'),
    svc: Services = Depends(services),
) -> JSONResponse:
    p = parse_params(ReconstructionParams, params)
    if p.fx is None and p.calibration is None and calibration is None:
        raise ApiError(422, "missing intrinsics: give fx, fy, cx, cy (pixels) in params, or a calibration file",
                       "invalid_parameters")
    if media.size == 0:
        raise ApiError(400, f"{media.filename or 'media'} is empty", "empty_file")
    uploads = [Upload("media", media.file, {"filename": media.filename, "content_type": media.content_type})]
    if calibration is not None:
        check_size(calibration, svc.settings.max_upload_bytes)
        uploads.append(Upload("calibration", calibration.file, {"filename": calibration.filename}))
    return job_accepted(await create_job(svc, RECONSTRUCT_JOB, p, uploads))
