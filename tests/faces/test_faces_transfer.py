"""Impression transfer vectors: Fisher (LDA) and SVM (eq. 5), and eq. 8."""
from __future__ import annotations

import numpy as np
import pytest
from sklearn.svm import SVC

from workers.faces.synthetic import EXPRESSIONS, expression_face, random_person, template
from workers.faces.transfer import (C_GRID, apply_transfer, fisher_direction, fit_svm, fit_svm_auto,
                                    nearest_support_direction)
from workers.faces.transform import transform_vertices


def test_nearest_support_vectors_on_a_constructed_case():
    sv = np.array([
        [1.0, 1.0], [2.0, 0.0], [9.0, 9.0],      # positive: distances sqrt2, 2, ~12.7 from the origin
        [-1.0, 0.0], [0.0, -3.0], [-4.0, 4.0],   # negative: distances 1, 3, ~5.7
    ])
    positive = np.array([True, True, True, False, False, False])
    f = np.zeros(2)
    # m = 2 nearest positives: (1,1), (2,0) -> mean (1.5, 0.5); n = 2 nearest negatives: (-1,0), (0,-3).
    expected = np.array([1.5, 0.5]) - np.array([-0.5, -1.5])
    np.testing.assert_allclose(nearest_support_direction(f, sv, positive, 2, 2), expected / np.linalg.norm(expected))
    # m = n = 1 from another input: nearest positive (9,9), nearest negative (-4,4).
    w = nearest_support_direction(np.array([5.0, 8.0]), sv, positive, 1, 1)
    np.testing.assert_allclose(w, np.array([13.0, 5.0]) / np.hypot(13, 5))
    # Asking for more neighbours than there are uses all of them.
    all_pos, all_neg = sv[:3].mean(axis=0), sv[3:].mean(axis=0)
    np.testing.assert_allclose(nearest_support_direction(f, sv, positive, 10, 10),
                               (all_pos - all_neg) / np.linalg.norm(all_pos - all_neg))


def test_fit_svm_keeps_sklearns_support_vectors_and_decision():
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.normal(2.0, 1.0, (30, 3)), rng.normal(-1.0, 1.0, (60, 3))]) * 50.0
    y = np.arange(90) < 30
    svm = fit_svm(x, y, c=0.5)
    scale = np.sqrt(np.mean(np.sum(x**2, axis=1)))  # the SVC sees unit-RMS scores
    ref = SVC(kernel="linear", C=0.5, class_weight="balanced").fit(x / scale, y.astype(int))
    np.testing.assert_allclose(svm.support_vectors, ref.support_vectors_ * scale)
    np.testing.assert_array_equal(svm.positive, y[ref.support_])
    np.testing.assert_allclose(svm.decision(x), ref.decision_function(x / scale), atol=1e-9)
    assert svm.positive.any() and (~svm.positive).any()
    # Units do not matter: the same points in other units give the same support vectors.
    again = fit_svm(x / 100.0, y, c=0.5)
    np.testing.assert_allclose(again.support_vectors * 100.0, svm.support_vectors)
    np.testing.assert_allclose(again.decision(x / 100.0), svm.decision(x), atol=1e-9)


def test_fisher_direction_is_the_lda_solution():
    rng = np.random.default_rng(4)
    cov = np.array([[4.0, 1.5], [1.5, 1.0]])
    chol = np.linalg.cholesky(cov)
    pos = rng.standard_normal((500, 2)) @ chol.T + [1.0, 1.0]
    neg = rng.standard_normal((500, 2)) @ chol.T
    scores, labels = np.concatenate([pos, neg]), np.arange(1000) < 500
    w = fisher_direction(scores, labels, shrinkage=0.0)
    within = np.cov(pos.T) + np.cov(neg.T)
    expected = np.linalg.solve(within, pos.mean(0) - neg.mean(0))
    np.testing.assert_allclose(w, expected / np.linalg.norm(expected), atol=1e-9)
    # Full shrinkage degenerates to the difference of the means.
    diff = pos.mean(0) - neg.mean(0)
    np.testing.assert_allclose(fisher_direction(scores, labels, shrinkage=1.0), diff / np.linalg.norm(diff))
    assert np.linalg.norm(fisher_direction(scores, labels)) == pytest.approx(1.0)


def test_q_zero_is_the_identity_of_eq_8():
    f = np.array([1.0, -2.0, 3.0])
    np.testing.assert_array_equal(apply_transfer(f, np.array([0.6, 0.8, 0.0]), 0.0), f)
    np.testing.assert_allclose(apply_transfer(f, np.array([0.6, 0.8, 0.0]), 2.0), [2.2, -0.4, 3.0])


@pytest.mark.parametrize("method", ["svm", "fisher"])
def test_transfer_vectors_raise_the_svc_decision_value(default_model, method):
    """On unseen people, Q > 0 moves a non-emphasised expression (the paper's input) towards the
    impression's side of its SVC, and further for larger Q. From a neutral or an already strong
    face, eq. 5 does not guarantee it: the SVM vector is a local difference of support vectors."""
    tpl = template()
    rises = []
    for seed in range(100, 106):
        person = random_person(np.random.default_rng(seed))
        for expression in EXPRESSIONS:
            for intensity in (0.0, 0.4, 0.8):
                x = expression_face(tpl, person, expression if intensity else "neutral", intensity)
                small = transform_vertices(default_model, x, expression, method, 0.2)
                large = transform_vertices(default_model, x, expression, method, 0.6)
                rises.append(small.decision_before < small.decision_after < large.decision_after)
                if intensity == 0.4:
                    assert rises[-1], (seed, expression)
    assert np.mean(rises) >= (1.0 if method == "fisher" else 0.95)


def test_svm_direction_depends_on_the_input_and_fisher_does_not(face_model):
    tpl = template()
    person = random_person(np.random.default_rng(8))
    weak = expression_face(tpl, person, "smile_open", 0.3)
    strong = expression_face(tpl, person, "smile_open", 1.0)
    svm = [transform_vertices(face_model, x, "smile_open", "svm", 1.0).direction for x in (weak, strong)]
    fisher = [transform_vertices(face_model, x, "smile_open", "fisher", 1.0).direction for x in (weak, strong)]
    np.testing.assert_array_equal(fisher[0], fisher[1])
    assert not np.allclose(svm[0], svm[1])
    for d in svm + fisher:
        assert np.linalg.norm(d) == pytest.approx(1.0)


def test_auto_c_is_the_softest_that_separates():
    rng = np.random.default_rng(6)
    x = np.concatenate([rng.normal(1.0, 1.0, (40, 2)), rng.normal(-1.0, 1.0, (80, 2))])
    y = np.arange(120) < 40
    svm, c = fit_svm_auto(x, y, min_accuracy=0.8)
    assert c in C_GRID
    hit = svm.decision(x) > 0
    assert 0.5 * (hit[y].mean() + (~hit[~y]).mean()) >= 0.8
    softer = [g for g in C_GRID if g < c]
    for g in softer:
        s = fit_svm(x, y, g)
        h = s.decision(x) > 0
        assert 0.5 * (h[y].mean() + (~h[~y]).mean()) < 0.8
    # An impossible target keeps the hardest margin.
    assert fit_svm_auto(x, y, min_accuracy=1.01)[1] == C_GRID[-1]
