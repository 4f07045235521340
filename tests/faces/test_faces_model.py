"""The morphable model: PCA (eqs. 1-3), projection (eq. 7), reconstruction (eq. 9), save/load."""
from __future__ import annotations

import numpy as np
import pytest

from workers.faces.errors import FaceInputError
from workers.faces.model import load_face_model
from workers.faces.morphable import MorphableModel
from workers.faces.neutral import estimate_neutral
from workers.faces.pca import fit_pca
from workers.faces.synthetic import EXPRESSIONS, expression_face, random_person, template
from workers.faces.train import TrainSettings, train_face_model


def test_pca_matches_numpy_svd_and_is_orthonormal():
    rng = np.random.default_rng(0)
    data = rng.standard_normal((30, 5)) @ rng.standard_normal((5, 200)) + rng.standard_normal(200)
    mean, basis, variances, total = fit_pca(data, variance=1.0, max_components=50)
    assert basis.shape == (200, 5)  # capped by the rank
    np.testing.assert_allclose(mean, data.mean(axis=0))
    np.testing.assert_allclose(basis.T @ basis, np.eye(5), atol=1e-10)
    sing = np.linalg.svd(data - mean, compute_uv=False)
    np.testing.assert_allclose(variances, sing[:5] ** 2 / 29, rtol=1e-8)
    np.testing.assert_allclose(total, np.sum(sing**2) / 29, rtol=1e-8)


def test_k_is_the_smallest_count_reaching_the_variance_target():
    rng = np.random.default_rng(1)
    scales = np.array([10.0, 5.0, 2.0, 1.0, 0.5])
    data = rng.standard_normal((400, 5)) * scales @ np.linalg.qr(rng.standard_normal((40, 5)))[0].T
    _, _, variances, total = fit_pca(data, variance=0.9)
    cumulative = np.cumsum(variances) / total
    assert cumulative[-1] >= 0.9 and (len(variances) == 1 or cumulative[-2] < 0.9)
    assert fit_pca(data, variance=0.999, max_components=2)[1].shape[1] == 2


def _morph(face_dataset, variance):
    mean, basis, variances, total = fit_pca(face_dataset.displacements(), variance, 500)
    neutral = face_dataset.vertices[face_dataset.expressions == "neutral"].mean(axis=0)
    return MorphableModel(neutral, mean, basis, variances, total, face_dataset.topology)


def test_pca_round_trip_on_generated_faces(face_dataset):
    """Eq. 7 then eq. 9 with the person's own neutral face gives the face back."""
    neutrals = face_dataset.vertices[face_dataset.neutral_index()]
    full = _morph(face_dataset, 1.0)
    for x, base in zip(face_dataset.vertices[::7], neutrals[::7]):
        f = full.project(x - base)
        np.testing.assert_allclose(full.reconstruct(f, base), x, atol=1e-8)
    # With K < rank, the squared error summed over the training faces is exactly the variance
    # left out: (M - 1) * (total - sum of the K kept eigenvalues).
    reduced = _morph(face_dataset, 0.998)
    err = sum(np.sum((reduced.reconstruct(reduced.project(x - b), b) - x) ** 2)
              for x, b in zip(face_dataset.vertices, neutrals))
    left_out = (len(neutrals) - 1) * (reduced.total_variance - reduced.variances.sum())
    assert reduced.n_components < full.n_components
    assert err == pytest.approx(left_out, rel=1e-8)
    assert reduced.explained_ratio() >= 0.998


def test_projection_of_a_batch_equals_single_projections(face_model, face_dataset):
    disp = face_dataset.displacements()[:5]
    batch = face_model.morph.project(disp)
    assert batch.shape == (5, face_model.morph.n_components)
    np.testing.assert_allclose(batch[3], face_model.morph.project(disp[3].reshape(-1, 3)))


def test_mahalanobis_of_the_mean_is_zero_and_scales_with_sigma(face_model):
    morph = face_model.morph
    assert morph.mahalanobis(np.zeros(morph.n_components)) == 0
    f = np.zeros(morph.n_components)
    f[0] = 2 * np.sqrt(morph.variances[0])
    assert morph.mahalanobis(f) == pytest.approx(2.0)


def test_neutral_estimate_recovers_an_unseen_persons_neutral_face(face_model):
    tpl = template()
    person = random_person(np.random.default_rng(77))
    truth = expression_face(tpl, person, "neutral")
    for expression in EXPRESSIONS:
        x = expression_face(tpl, person, expression, 0.8)
        est = estimate_neutral(face_model.morph, face_model.identity, x)
        # Much closer than the mean face (which misses the identity entirely).
        assert np.abs(est - truth).mean() < 0.3 * np.abs(face_model.morph.neutral - truth).mean()


def test_save_load_round_trip(tmp_path, face_model):
    path = tmp_path / "model.npz"
    face_model.save(path)
    back = load_face_model(path)
    assert back.impressions == face_model.impressions and back.q_unit == face_model.q_unit
    assert back.summary() == face_model.summary()
    np.testing.assert_array_equal(back.morph.basis, face_model.morph.basis)
    np.testing.assert_array_equal(back.fisher, face_model.fisher)
    np.testing.assert_array_equal(back.identity.cross, face_model.identity.cross)
    for a, b in zip(back.svms, face_model.svms):
        np.testing.assert_array_equal(a.support_vectors, b.support_vectors)
        np.testing.assert_array_equal(a.positive, b.positive)
        assert a.intercept == b.intercept
    assert back.morph.topology.same_topology(face_model.morph.topology)
    assert load_face_model(face_model.to_bytes()).impressions == face_model.impressions


def test_loading_something_else_is_an_input_error(tmp_path):
    path = tmp_path / "x.npz"
    np.savez(path, a=np.zeros(3))
    with pytest.raises(FaceInputError, match="not a face model"):
        load_face_model(path)
    with pytest.raises(FaceInputError, match="not a face model"):
        load_face_model(b"definitely not a zip")


def test_training_settings_reach_the_model(face_dataset):
    model = train_face_model(face_dataset, TrainSettings(variance=0.9, max_components=3, m=5, n=2))
    assert model.morph.n_components <= 3 and (model.m, model.n) == (5, 2)
    np.testing.assert_allclose(np.linalg.norm(model.fisher, axis=1), 1.0)
    assert model.impressions == EXPRESSIONS
