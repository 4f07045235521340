"""Service entry points of the face transformer.

- ``run_face_training(ctx)``: job kind ``faces.train``. Input ``dataset`` (a zip, see
  :mod:`workers.faces.dataset`) or params ``{"source": "synthetic"}``; parameters
  :class:`FaceTrainParams`; results ``model.npz`` and ``summary.json``.
- ``transform_mesh_bytes(...)``: a synchronous transform for the web layer (a few ms plus the
  mesh parsing), parameters :class:`FaceTransformParams`; returns the mesh in the input's
  format and a side-by-side preview PNG.
- ``ensure_default_model(path)``: the model trained from the synthetic generator on first use.
"""
from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Any, Callable, Literal, NamedTuple

from pydantic import BaseModel, ConfigDict, Field

from workers.common.jobctx import JobContext, JobInputError
from workers.faces.dataset import load_dataset_zip
from workers.faces.errors import FaceInputError
from workers.faces.mesh import detect_format, read_mesh, replace_vertices
from workers.faces.model import FaceModel, load_face_model
from workers.faces.preview import preview_png
from workers.faces.synthetic import generate_dataset
from workers.faces.train import TrainSettings, train_face_model
from workers.faces.transform import MAX_NEIGHBOURS, Q_LIMIT, transform_mesh
from workers.registry import JobKind

DATASET_INPUT = "dataset"
MODEL_RESULT = "model.npz"
SUMMARY_RESULT = "summary.json"


class FaceTrainParams(BaseModel):
    """Parameters of a ``faces.train`` job.

    ``source``: ``"dataset"`` (the uploaded zip, input ``dataset``), ``"synthetic"`` (the
    procedural generator), or ``"auto"`` (the zip when one was uploaded). ``people`` and
    ``seed`` apply to the synthetic source only.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)  # NaN/Infinity: never a valid value

    source: Literal["auto", "dataset", "synthetic"] = "auto"
    people: int = Field(40, ge=2, le=400, description="synthetic source: number of people (7 faces each)")
    seed: int = Field(0, ge=0, le=2**31 - 1, description="synthetic source: random seed")
    variance: float = Field(0.998, gt=0.5, le=1.0, description="PCA explained-variance target")
    max_components: int = Field(60, ge=1, le=500, description="cap on the PCA components K")
    svm_c: float | None = Field(None, gt=0.0, le=1e6,
                                description="C of the linear SVCs on unit-RMS scores; null: chosen per impression")
    balanced: bool = Field(True, description="weight the SVC classes inversely to their sizes")
    m: int = Field(10, ge=1, le=MAX_NEIGHBOURS, description="default positive neighbours of eq. 5")
    n: int = Field(10, ge=1, le=MAX_NEIGHBOURS, description="default negative neighbours of eq. 5")

    def settings(self) -> TrainSettings:
        return TrainSettings(variance=self.variance, max_components=self.max_components, svm_c=self.svm_c,
                             balanced=self.balanced, m=self.m, n=self.n)


class FaceTransformParams(BaseModel):
    """Parameters of a transform; field names match :func:`transform_mesh_bytes`'s keywords.

    ``q`` is in units of the model's typical expression size (Q = 1: a step as large as a
    training expression). ``m``/``n`` default to the model's. ``keep_detail`` false gives eq. 9
    exactly (the output is rebuilt from the K components; fine detail off the model is lost).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)  # NaN/Infinity: never a valid value

    impression: str = Field(..., min_length=1, max_length=40, description="e.g. smile_open")
    method: Literal["svm", "fisher"] = "svm"
    q: float = Field(1.0, ge=-Q_LIMIT, le=Q_LIMIT, description="intensity Q of eq. 8")
    m: int | None = Field(None, ge=1, le=MAX_NEIGHBOURS)
    n: int | None = Field(None, ge=1, le=MAX_NEIGHBOURS)
    keep_detail: bool = True
    estimate_neutral: bool = Field(True, description="without a neutral mesh: estimate it (else the mean face)")
    preview_size: int = Field(320, ge=64, le=1024, description="side of each preview panel, pixels")


class FaceTransformOutput(NamedTuple):
    """``mesh``: the transformed file in the input's format; ``preview_png``: input and output side
    by side; ``info``: JSON-able facts (SVC decision values before and after, Mahalanobis distances, ...)."""

    mesh: bytes
    preview_png: bytes
    info: dict[str, Any]


def run_face_training(ctx: JobContext) -> dict[str, Any]:
    """Train a face model from the uploaded ``dataset`` zip or the synthetic generator."""
    params = FaceTrainParams.model_validate(ctx.params)
    uploaded = DATASET_INPUT in ctx.inputs
    source = params.source if params.source != "auto" else ("dataset" if uploaded else "synthetic")
    if source == "dataset" and not uploaded:
        raise JobInputError("upload a dataset zip (input 'dataset') or train with source 'synthetic'")
    if source == "synthetic" and uploaded:
        raise JobInputError("a dataset zip was uploaded but source is 'synthetic': send one or the other")
    try:
        if source == "dataset":
            dataset = load_dataset_zip(ctx.input_path(DATASET_INPUT),
                                       progress=lambda f, s: ctx.progress(0.5 * f, s))
        else:
            ctx.progress(0.0, "generating synthetic faces")
            dataset = generate_dataset(params.people, params.seed)
        model = train_face_model(dataset, params.settings(), progress=lambda f, s: ctx.progress(0.5 + 0.45 * f, s))
    except FaceInputError as exc:
        raise JobInputError(str(exc)) from None
    ctx.progress(0.95, "saving the model")
    ctx.write_result(MODEL_RESULT, model.to_bytes())
    summary = {"source": source, **model.summary()}
    ctx.write_result(SUMMARY_RESULT, (json.dumps(summary, indent=2) + "\n").encode())
    ctx.progress(1.0, "done")
    return summary


def load_model(path: str | Path) -> FaceModel:
    """A saved model, cached per file version (path, size, modification time)."""
    path = Path(path)
    try:
        stat = path.stat()
    except OSError:
        raise FaceInputError(f"no face model at {path}") from None
    return _load_cached(str(path.resolve()), stat.st_size, stat.st_mtime_ns)


@functools.lru_cache(maxsize=8)
def _load_cached(path: str, size: int, mtime_ns: int) -> FaceModel:
    return load_face_model(path)


def transform_mesh_bytes(
    model: FaceModel | str | Path, mesh_bytes: bytes, filename: str, impression: str,
    method: str = "svm", q: float = 1.0, *, m: int | None = None, n: int | None = None,
    keep_detail: bool = True, estimate_neutral: bool = True, preview_size: int = 320,
    neutral_bytes: bytes | None = None, neutral_filename: str | None = None,
) -> FaceTransformOutput:
    """Transform an uploaded OBJ/PLY face (``filename`` or a bare ``"obj"``/``"ply"`` names the format).

    ``neutral_bytes``: optionally the same person's neutral face (``X_neutral`` of eq. 6); else it
    is estimated from the input (``estimate_neutral``) or taken as the model's mean neutral face.
    Raises FaceInputError for anything the user can fix.
    """
    face_model = model if isinstance(model, FaceModel) else load_model(model)
    fmt = detect_format(mesh_bytes, filename)
    mesh = read_mesh(mesh_bytes, filename)
    neutral = None
    if neutral_bytes is not None:
        try:
            neutral = read_mesh(neutral_bytes, neutral_filename or filename)
        except FaceInputError as exc:
            raise FaceInputError(f"neutral mesh: {exc}") from None
    out_mesh, result = transform_mesh(face_model, mesh, impression, method, q, neutral=neutral,
                                      estimate_neutral=estimate_neutral, m=m, n=n, keep_detail=keep_detail)
    png = preview_png(mesh.vertices, out_mesh.vertices, face_model.morph.topology.triangles(),
                      ("input", f"{impression} {method} Q={q:g}"), preview_size)
    info = {"impression": impression, "method": method, "q": q, "format": fmt,
            "n_vertices": mesh.n_vertices, **result.info()}
    return FaceTransformOutput(replace_vertices(mesh_bytes, out_mesh.vertices, filename), png, info)


def build_default_model(progress: Callable[[float, str], None] | None = None) -> FaceModel:
    """The default model: the paper's design (40 people x 7 faces) from the synthetic generator."""
    params = FaceTrainParams(source="synthetic")
    return train_face_model(generate_dataset(params.people, params.seed), params.settings(), progress)


def ensure_default_model(path: str | Path, progress: Callable[[float, str], None] | None = None) -> FaceModel:
    """Load the default model from ``path``, training and saving it there first if it is missing."""
    path = Path(path)
    if path.exists():
        return load_model(path)
    model = build_default_model(progress)
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(path)
    return model


TRAIN_JOB = JobKind("faces.train", run_face_training, FaceTrainParams)
JOBS = (TRAIN_JOB,)
