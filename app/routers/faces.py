"""3D face models: train (a job), list, and transform a mesh by an impression transfer vector."""
from __future__ import annotations

import asyncio
import base64
import datetime as dt
import threading
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Depends, File, UploadFile
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field

from app.auth import principal, require_key
from app.keys import Principal
from app.errors import ApiError
from app.limits import BATCH_BODY
from app.jobstore import JobState, as_utc
from app.routers.jobs import JobOut, job_accepted
from app.params_form import params_form
from app.services import Services, Upload, create_job, run_compute, services
from app.sync_work import BUSY_RESPONSE
from app.uploads import read_upload
from workers.faces.dataset import check_dataset_zip
from workers.faces.errors import FaceInputError
from workers.faces.mesh import parse_estimate
from workers.faces.model import FaceModel
from workers.faces.job import (MODEL_RESULT, TRAIN_JOB, FaceTrainParams, FaceTransformParams, ensure_default_model,
                               load_model, transform_mesh_bytes)
from workers.runtime import results_prefix
from workers.storage import BlobNotFound

router = APIRouter(prefix="/v1/face-models", tags=["faces"], dependencies=[Depends(require_key)])

DEFAULT_ID = "default"
_default_lock = threading.Lock()


class FaceModelOut(BaseModel):
    id: str = Field(description="'default' (synthetic, trained on first use) or the id of the training job")
    created_at: dt.datetime | None
    summary: dict[str, Any] = Field(description="impressions, people, PCA components, ...")


class FaceModelList(BaseModel):
    models: list[FaceModelOut]


class TransformOut(BaseModel):
    mesh_base64: str = Field(description="the transformed mesh, in the input's format (OBJ or PLY)")
    format: str
    preview_png_base64: str = Field(description="input and output rendered side by side, PNG")
    info: dict[str, Any] = Field(description="SVC decision values before and after, distances, ...")


def _default_path(svc: Services) -> Path:
    return svc.settings.data_dir / "faces" / "default_model.npz"


def _default_model(svc: Services) -> FaceModel:
    with _default_lock:  # two first requests train it once
        return ensure_default_model(_default_path(svc))


async def _model(model_id: str, svc: Services, who: Principal) -> FaceModel:
    if model_id == DEFAULT_ID:
        return await run_compute(svc, lambda: _default_model(svc))  # trains on first use: CPU work
    job = await asyncio.to_thread(svc.jobs.get, model_id)
    if job is None or job.kind != TRAIN_JOB.name or not who.owns(job.created_by):
        raise ApiError(404, f"no face model {model_id!r}: use 'default' or the id of a faces training job",
                       "model_not_found")
    if job.state != JobState.succeeded.value:
        raise ApiError(409, f"face model {model_id} is not ready: its training job is {job.state}"
                            + (f" ({job.error})" if job.error else ""), "model_not_ready")
    try:
        path = await asyncio.to_thread(svc.store.local_path, f"{results_prefix(model_id)}/{MODEL_RESULT}")
        return await run_compute(svc, load_model, path)
    except (BlobNotFound, FaceInputError):  # its message names a server path: not for the client
        raise ApiError(410, f"the files of face model {model_id} are gone or unreadable", "model_gone") from None


@router.post("", status_code=202, response_model=JobOut, openapi_extra=BATCH_BODY,
             summary="Train a face model: from a dataset zip (meshes + manifest.csv) or the synthetic generator")
async def train_model(
    dataset: UploadFile | None = File(None, description="zip of registered meshes with manifest.csv (person, expression, file)"),
    p: FaceTrainParams = params_form(FaceTrainParams, ', e.g. {"source": "synthetic"}'),
    svc: Services = Depends(services),
    who: Principal = Depends(principal),
) -> JSONResponse:
    if dataset is None and p.source == "dataset":
        raise ApiError(422, "source 'dataset' needs a dataset zip in the 'dataset' field", "invalid_request")
    if dataset is not None and p.source == "synthetic":
        raise ApiError(422, "a dataset zip was sent but source is 'synthetic': send one or the other", "invalid_request")
    if dataset is not None:
        await asyncio.to_thread(check_dataset_zip, dataset.file, svc.settings.zip_limits, dataset.filename or
                                "the dataset zip")
    uploads = [Upload("dataset", dataset.file, {"filename": dataset.filename})] if dataset is not None else []
    return job_accepted(await create_job(svc, who, TRAIN_JOB, p, uploads))


@router.get("", response_model=FaceModelList, summary="The face models: the default and every one the key trained")
async def list_models(svc: Services = Depends(services), who: Principal = Depends(principal)) -> FaceModelList:
    jobs = await asyncio.to_thread(svc.jobs.list, JobState.succeeded.value, TRAIN_JOB.name, 500, 0,
                                   None if who.is_admin else who.id)
    models = [FaceModelOut(id=DEFAULT_ID, created_at=None,
                           summary={"source": "synthetic", "trained": _default_path(svc).exists()})]
    models += [FaceModelOut(id=j.id, created_at=as_utc(j.finished_at), summary=(j.result or {}).get("summary", {}))
               for j in jobs]
    return FaceModelList(models=models)


@router.post("/{model_id}/transform", response_model=TransformOut,
             responses={409: {"description": "the model's training job has not succeeded"},
                        410: {"description": "the model's files are no longer stored"},
                        503: BUSY_RESPONSE},
             summary="Strengthen an impression of a face mesh (OBJ/PLY): the mesh back in its format and a preview")
async def transform(
    model_id: str,
    mesh: UploadFile = File(..., description="the face, OBJ or PLY, registered to the model's topology"),
    neutral: UploadFile | None = File(None, description="the same person's neutral face (optional)"),
    p: FaceTransformParams = params_form(FaceTransformParams, ', e.g. {"impression": "smile_open", "method": "svm", '
                                                              '"q": 1.5}', required=True),
    svc: Services = Depends(services),
    who: Principal = Depends(principal),
) -> TransformOut:
    model = await _model(model_id, svc, who)
    mesh_bytes = await read_upload(mesh, svc.settings.max_upload_bytes)
    neutral_bytes = await read_upload(neutral, svc.settings.max_upload_bytes) if neutral is not None else None
    neutral_name = neutral.filename if neutral is not None else None
    # on the bounded compute pool, within the memory budget of synchronous work (parsing a large upload takes ~12
    # bytes per byte before its topology is checked): parsing, transfer and the preview; a FaceInputError is a 422
    cost = parse_estimate(len(mesh_bytes) + len(neutral_bytes or b""))
    out = await svc.sync_work.run(cost, lambda: run_compute(svc, lambda: transform_mesh_bytes(
        model, mesh_bytes, mesh.filename or "mesh", **p.model_dump(),
        neutral_bytes=neutral_bytes, neutral_filename=neutral_name)))
    return TransformOut(mesh_base64=base64.b64encode(out.mesh).decode(), format=out.info["format"],
                        preview_png_base64=base64.b64encode(out.preview_png).decode(), info=out.info)
