"""The service entry points: the training job with a fake context, and the synchronous transform."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from pydantic import ValidationError

from workers.common.jobctx import JobInputError
from workers.faces import job
from workers.faces.dataset import write_dataset_zip
from workers.faces.errors import FaceInputError
from workers.faces.job import (FaceTrainParams, FaceTransformParams, ensure_default_model, run_face_training,
                               transform_mesh_bytes)
from workers.faces.mesh import read_mesh, write_mesh
from workers.faces.model import load_face_model
from tests.faces.meshes import demo_mesh
from workers.faces.synthetic import generate_dataset


@dataclass
class FakeContext:
    root: Path
    params: dict[str, Any]
    inputs: dict[str, str] = field(default_factory=dict)
    job_id: str = "job-1"
    kind: str = "faces.train"
    input_meta: dict[str, dict[str, Any]] = field(default_factory=dict)
    events: list[tuple[float, str]] = field(default_factory=list)

    def input_path(self, name: str) -> Path:
        return self.root / "in" / self.inputs[name]

    def read_input(self, name: str) -> bytes:
        return self.input_path(name).read_bytes()

    def result_path(self, name: str) -> Path:
        (self.root / "out").mkdir(exist_ok=True)
        return self.root / "out" / name

    def write_result(self, name: str, data: bytes) -> None:
        self.result_path(name).write_bytes(data)

    def progress(self, fraction: float, stage: str) -> None:
        self.events.append((fraction, stage))


def _context(tmp_path: Path, params: dict, dataset: bytes | None = None) -> FakeContext:
    (tmp_path / "in").mkdir()
    ctx = FakeContext(tmp_path, params)
    if dataset is not None:
        (tmp_path / "in" / "blob-1").write_bytes(dataset)
        ctx.inputs["dataset"] = "blob-1"
    return ctx


def test_training_job_on_synthetic_faces(tmp_path):
    ctx = _context(tmp_path, {"source": "synthetic", "people": 6, "seed": 3})
    summary = run_face_training(ctx)
    model = load_face_model(ctx.result_path("model.npz"))
    assert summary["source"] == "synthetic" and summary["n_faces_trained"] == 42
    assert json.loads(ctx.result_path("summary.json").read_text()) == summary
    assert list(model.impressions) == summary["impressions"]
    fractions = [f for f, _ in ctx.events]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0


def test_training_job_on_an_uploaded_zip(tmp_path):
    zipped = write_dataset_zip(generate_dataset(people=3, seed=4), "ply")
    ctx = _context(tmp_path, {}, zipped)  # source "auto" picks the upload
    summary = run_face_training(ctx)
    assert summary["source"] == "dataset" and summary["n_people"] == 3


@pytest.mark.parametrize("params,upload,message", [
    ({"source": "dataset"}, None, "upload a dataset zip"),
    ({"source": "synthetic"}, b"PK", "one or the other"),
    ({}, b"not a zip", "not a zip file"),
])
def test_training_job_input_errors(tmp_path, params, upload, message):
    with pytest.raises(JobInputError, match=message):
        run_face_training(_context(tmp_path, params, upload))


def test_params_models_reject_bad_values():
    with pytest.raises(ValidationError):
        FaceTrainParams(people=1)
    with pytest.raises(ValidationError):
        FaceTrainParams(unknown=1)
    with pytest.raises(ValidationError):
        FaceTransformParams(impression="smile_open", q=3.5)
    with pytest.raises(ValidationError):
        FaceTransformParams(impression="smile_open", method="pca")
    assert FaceTransformParams(impression="smile_open").model_dump()["method"] == "svm"


@pytest.mark.parametrize("fmt,binary", [("obj", False), ("ply", True), ("ply", False)])
def test_transform_bytes_keeps_the_input_format(face_model, fmt, binary):
    mesh = demo_mesh("smile_open", 0.4)
    data = write_mesh(mesh, fmt, binary)
    params = FaceTransformParams(impression="smile_open", q=1.0, preview_size=96)
    out = transform_mesh_bytes(face_model, data, f"face.{fmt}", **params.model_dump())
    assert out.mesh[:3] == data[:3]
    if fmt == "ply":
        assert out.mesh.split(b"end_header")[0] == data.split(b"end_header")[0]
    back = read_mesh(out.mesh, f"face.{fmt}")
    assert back.same_topology(mesh) and not np.allclose(back.vertices, mesh.vertices)
    png = cv2.imdecode(np.frombuffer(out.preview_png, np.uint8), cv2.IMREAD_COLOR)
    assert png.shape == (96, 196, 3)
    assert out.info["decision_after"] > out.info["decision_before"]
    assert out.info["format"] == fmt and out.info["neutral_source"] == "estimated"


def test_transform_bytes_with_a_neutral_and_from_a_saved_model(tmp_path, face_model):
    path = tmp_path / "m.npz"
    face_model.save(path)
    neutral = write_mesh(demo_mesh("neutral"), "obj")
    out = transform_mesh_bytes(path, write_mesh(demo_mesh("utter_o"), "obj"), "x.obj", "utter_o", "fisher", 0.5,
                               neutral_bytes=neutral, neutral_filename="n.obj")
    assert out.info["neutral_source"] == "given" and out.info["method"] == "fisher"


def test_transform_bytes_errors(face_model):
    good = write_mesh(demo_mesh(), "obj")
    with pytest.raises(FaceInputError, match="no vertices"):
        transform_mesh_bytes(face_model, b"just some text", "x.obj", "smile_open")
    with pytest.raises(FaceInputError, match="unknown impression"):
        transform_mesh_bytes(face_model, good, "x.obj", "sad")
    small = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    with pytest.raises(FaceInputError, match="expects 3584"):
        transform_mesh_bytes(face_model, small, "x.obj", "smile_open")
    with pytest.raises(FaceInputError, match="neutral mesh: no vertices"):
        transform_mesh_bytes(face_model, good, "x.obj", "smile_open", neutral_bytes=b"hello", neutral_filename="n.obj")
    with pytest.raises(FaceInputError, match="no face model"):
        transform_mesh_bytes("/nonexistent/model.npz", good, "x.obj", "smile_open")


def test_default_model_is_trained_once_and_then_loaded(tmp_path, monkeypatch, face_model):
    calls = []

    def fake_build(progress=None):
        calls.append(1)
        return face_model

    monkeypatch.setattr(job, "build_default_model", fake_build)
    path = tmp_path / "cache" / "default.npz"
    first = ensure_default_model(path)
    second = ensure_default_model(path)
    assert calls == [1] and path.exists()
    assert first.impressions == second.impressions


def test_the_real_default_model_has_the_papers_six_impressions(default_model):
    assert default_model.impressions == ("utter_a", "utter_i", "utter_u", "utter_o", "smile_closed", "smile_open")
    assert default_model.meta["n_faces_trained"] == 280
    # C is the softest reaching 90 % balanced training accuracy: soft margins, many support vectors.
    assert min(default_model.meta["svm_training_accuracy"].values()) > 0.8
