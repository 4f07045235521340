"""Transforming meshes (eqs. 6-9): Q = 0, the effect of Q, and the inputs a user can get wrong."""
from __future__ import annotations

import numpy as np
import pytest

from workers.faces.errors import FaceInputError
from workers.faces.mesh import Mesh
from workers.faces.synthetic import expression_face, random_person, template
from workers.faces.train import TrainSettings, train_face_model
from workers.faces.transform import transform_mesh, transform_vertices


@pytest.fixture(scope="module")
def person_faces():
    tpl = template()
    person = random_person(np.random.default_rng(42))
    return {
        "neutral": expression_face(tpl, person, "neutral"),
        "weak": expression_face(tpl, person, "smile_open", 0.4),
        "strong": expression_face(tpl, person, "smile_open", 1.0),
    }


@pytest.mark.parametrize("method", ["svm", "fisher"])
def test_q_zero_is_the_identity(face_model, person_faces, method):
    x = person_faces["weak"]
    out = transform_vertices(face_model, x, "smile_open", method, 0.0)
    np.testing.assert_array_equal(out.vertices, x)
    assert out.max_displacement == 0.0 and out.decision_after == out.decision_before


def test_q_zero_with_eq9_and_all_components_is_the_identity(face_dataset, person_faces):
    model = train_face_model(face_dataset, TrainSettings(variance=1.0, max_components=500))
    x, neutral = person_faces["weak"], person_faces["neutral"]
    out = transform_vertices(model, x, "smile_open", "svm", 0.0, neutral=neutral, keep_detail=False)
    # Eq. 9 rebuilds from the components only; the person's own expression lies in their span
    # up to the part no training face shows (scanner noise, person-specific style).
    assert np.sqrt(np.mean(np.sum((out.vertices - x) ** 2, axis=1))) < 0.05


def test_eq9_output_lies_in_the_model(face_model, person_faces):
    x, neutral = person_faces["weak"], person_faces["neutral"]
    out = transform_vertices(face_model, x, "smile_open", "svm", 0.7, neutral=neutral, keep_detail=False)
    np.testing.assert_allclose(out.vertices, face_model.morph.reconstruct(out.new_scores, neutral), atol=1e-10)
    detail = transform_vertices(face_model, x, "smile_open", "svm", 0.7, neutral=neutral)
    morph = face_model.morph
    np.testing.assert_allclose(detail.vertices - x, (morph.basis @ (detail.new_scores - detail.scores)).reshape(-1, 3))


def test_step_length_is_q_times_the_unit(face_model, person_faces):
    out = transform_vertices(face_model, person_faces["weak"], "smile_open", "svm", 1.5)
    assert np.linalg.norm(out.new_scores - out.scores) == pytest.approx(1.5 * face_model.q_unit)
    assert np.linalg.norm(out.vertices - person_faces["weak"]) == pytest.approx(1.5 * face_model.q_unit)


def test_emphasis_brings_a_weak_expression_towards_the_persons_strong_one(face_model, person_faces):
    weak, strong = person_faces["weak"], person_faces["strong"]
    before = np.linalg.norm(weak - strong)
    out = transform_vertices(face_model, weak, "smile_open", "svm", 0.5, neutral=person_faces["neutral"])
    assert np.linalg.norm(out.vertices - strong) < 0.6 * before


def test_neutral_sources(face_model, person_faces):
    x = person_faces["weak"]
    given = transform_vertices(face_model, x, "smile_open", "svm", 1.0, neutral=person_faces["neutral"])
    estimated = transform_vertices(face_model, x, "smile_open", "svm", 1.0)
    mean = transform_vertices(face_model, x, "smile_open", "svm", 1.0, estimate_neutral=False)
    assert (given.neutral_source, estimated.neutral_source, mean.neutral_source) == ("given", "estimated", "mean")
    # The estimated neutral puts the face near where its true neutral does; the mean face does not.
    assert np.linalg.norm(estimated.scores - given.scores) < 0.3 * np.linalg.norm(mean.scores - given.scores)


def test_bad_requests_raise_input_errors(face_model, person_faces):
    x = person_faces["weak"]
    cases = [
        (dict(impression="angry"), "unknown impression 'angry'; this model knows: utter_a"),
        (dict(method="lda"), "unknown method"),
        (dict(q=3.5), "Q must be a number between -3 and 3"),
        (dict(q=float("nan")), "Q must be"),
        (dict(q="big"), "Q must be"),
        (dict(m=0), "m must be an integer"),
    ]
    for kwargs, message in cases:
        args = {"impression": "smile_open", "method": "svm", "q": 1.0} | kwargs
        with pytest.raises(FaceInputError, match=message):
            transform_vertices(face_model, x, **args)
    with pytest.raises(FaceInputError, match="expected"):
        transform_vertices(face_model, x[:-1], "smile_open")


def test_mesh_checks_topology_and_nan(face_model, person_faces):
    topo = face_model.morph.topology
    good = topo.with_vertices(person_faces["weak"])
    out, info = transform_mesh(face_model, good, "smile_open", "svm", 1.0)
    assert out.same_topology(good)
    other = Mesh.from_faces(good.vertices, topo.triangles()[:, ::-1])
    with pytest.raises(FaceInputError, match="different faces"):
        transform_mesh(face_model, other, "smile_open")
    with pytest.raises(FaceInputError, match="mesh has 3 vertices"):
        transform_mesh(face_model, Mesh.from_faces(np.eye(3), [[0, 1, 2]]), "smile_open")
    nan = good.vertices.copy()
    nan[10] = np.nan
    with pytest.raises(FaceInputError, match="NaN"):
        transform_mesh(face_model, good.with_vertices(nan), "smile_open")
    with pytest.raises(FaceInputError, match="neutral mesh: .*NaN"):
        transform_mesh(face_model, good, "smile_open", neutral=good.with_vertices(nan))
