"""Impression transfer vectors (the paper's III): the Fisher method and the SVM method.

Both live in the morphable model's parameter space (PCA scores ``f``, shape (K,)). The Fisher
vector ``e`` is one unit direction per impression (LDA, class against the rest). The SVM vector
``w`` (eq. 5) is computed per input face from the support vectors of a linear SVC nearest to
it: ``w = mean(m nearest positive SVs) - mean(n nearest negative SVs)``, normalised. Either is
applied as ``f' = f + Q * direction`` (eqs. 4 and 8).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def fisher_direction(scores: np.ndarray, labels: np.ndarray, shrinkage: float | None = None) -> np.ndarray:
    """Unit (K,) Fisher discriminant direction from the rest towards the class.

    ``scores``: (M, K) float parameters; ``labels``: (M,) bool, True for the class.
    ``w = ((1 - a) S_W + a tr(S_W)/K I)^-1 (mu_class - mu_rest)`` with the pooled within-class
    scatter ``S_W`` shrunk towards a multiple of the identity by ``a`` (``None``: the Ledoit-Wolf
    estimate, as in regularised LDA), which keeps it invertible when K is close to M.
    """
    scores = np.asarray(scores, dtype=np.float64)
    labels = np.asarray(labels, dtype=bool)
    pos, neg = scores[labels], scores[~labels]
    if len(pos) == 0 or len(neg) == 0:
        raise ValueError("the Fisher direction needs samples in the class and in the rest")
    centred = np.concatenate([pos - pos.mean(axis=0), neg - neg.mean(axis=0)])
    if shrinkage is None:
        from sklearn.covariance import ledoit_wolf_shrinkage  # training only: keeps 1 s of imports off start-up

        shrinkage = float(ledoit_wolf_shrinkage(centred, assume_centered=True))
    k = scores.shape[1]
    within = centred.T @ centred
    target = max(np.trace(within), np.finfo(float).tiny) / k * np.eye(k)
    w = np.linalg.solve((1.0 - shrinkage) * within + shrinkage * target, pos.mean(axis=0) - neg.mean(axis=0))
    return _unit(w)


@dataclass(frozen=True, eq=False)
class SvmTransfer:
    """A trained linear SVC for one impression, kept as the arrays eq. 5 needs.

    ``support_vectors``: (S, K) float64; ``positive``: (S,) bool (the support vector's class);
    ``coef``: (K,) and ``intercept``: the decision function ``f @ coef + intercept`` (> 0: class).
    """

    support_vectors: np.ndarray
    positive: np.ndarray
    coef: np.ndarray
    intercept: float

    def decision(self, scores: np.ndarray) -> np.ndarray:
        """SVC decision values of (..., K) parameters: shape (...), > 0 on the impression's side."""
        return np.asarray(scores, dtype=np.float64) @ self.coef + self.intercept

    def direction(self, f: np.ndarray, m: int, n: int) -> np.ndarray:
        """Unit (K,) transfer vector ``w`` of eq. 5 for the (K,) input face ``f``."""
        w = nearest_support_direction(f, self.support_vectors, self.positive, m, n)
        # Equal neighbour means give no direction; the boundary normal is the natural limit.
        return w if np.any(w) else _unit(self.coef)


def fit_svm(scores: np.ndarray, labels: np.ndarray, c: float = 1.0, balanced: bool = True) -> SvmTransfer:
    """Train a linear SVC (scikit-learn ``SVC(kernel="linear")``) of class against the rest.

    ``scores``: (M, K) float; ``labels``: (M,) bool. The SVC sees the scores divided by their RMS
    row norm, so that ``c`` means the same whatever the mesh units (a uniform scale changes neither
    the support vectors' neighbourhoods nor any direction). ``balanced`` weights the classes
    inversely to their sizes (one impression against six other classes is 1:6 in the paper's design).
    """
    scores = np.asarray(scores, dtype=np.float64)
    labels = np.asarray(labels, dtype=bool)
    if labels.all() or not labels.any():
        raise ValueError("the SVM needs samples in the class and in the rest")
    scale = float(np.sqrt(np.mean(np.sum(scores**2, axis=1)))) or 1.0
    from sklearn.svm import SVC  # training only: keeps 1 s of imports off start-up

    svc = SVC(kernel="linear", C=c, class_weight="balanced" if balanced else None)
    svc.fit(scores / scale, labels.astype(np.int64))
    return SvmTransfer(
        support_vectors=scores[svc.support_].copy(),
        positive=labels[svc.support_],
        coef=np.array(svc.coef_[0], dtype=np.float64) / scale,
        intercept=float(svc.intercept_[0]),
    )


C_GRID = (0.1, 0.3, 1.0, 3.0, 10.0, 100.0)


def fit_svm_auto(scores: np.ndarray, labels: np.ndarray, balanced: bool = True,
                 min_accuracy: float = 0.9) -> tuple[SvmTransfer, float]:
    """The softest SVC on ``C_GRID`` whose balanced training accuracy reaches ``min_accuracy``, and its C.

    Eq. 5 averages support vectors, so a soft margin (many of them, closer to the classes'
    local means) gives steadier directions than a hard one (a few extreme faces); but the SVC
    must still separate the impression. When no C reaches the accuracy, the hardest is kept.
    """
    labels = np.asarray(labels, dtype=bool)
    for c in C_GRID:
        svm = fit_svm(scores, labels, c, balanced)
        hit = svm.decision(scores) > 0
        if 0.5 * (hit[labels].mean() + (~hit[~labels]).mean()) >= min_accuracy:
            break
    return svm, c


def nearest_support_direction(
    f: np.ndarray, support_vectors: np.ndarray, positive: np.ndarray, m: int, n: int
) -> np.ndarray:
    """Unit (K,) ``w`` of eq. 5: mean of the m nearest positive support vectors minus the mean of
    the n nearest negative ones, nearest to (K,) ``f`` in Euclidean distance.

    ``support_vectors``: (S, K); ``positive``: (S,) bool. When a side has fewer support vectors
    than asked, all of them are used. Returns zeros when the two means coincide.
    """
    if m < 1 or n < 1:
        raise ValueError("m and n must be at least 1")
    dist = np.linalg.norm(support_vectors - np.asarray(f, dtype=np.float64), axis=1)
    pos = _nearest(support_vectors[positive], dist[positive], m)
    neg = _nearest(support_vectors[~positive], dist[~positive], n)
    return _unit(pos.mean(axis=0) - neg.mean(axis=0))


def _nearest(points: np.ndarray, dist: np.ndarray, k: int) -> np.ndarray:
    if len(points) == 0:
        raise ValueError("the SVM has no support vectors on one side")
    order = np.argsort(dist, kind="stable")[:k]
    return points[order]


def apply_transfer(f: np.ndarray, direction: np.ndarray, q: float) -> np.ndarray:
    """Eq. 8: ``f' = f + q * direction`` for (K,) or (B, K) ``f`` and a (K,) direction."""
    return np.asarray(f, dtype=np.float64) + q * np.asarray(direction, dtype=np.float64)


def _unit(v: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v)
    return v / norm if norm > 0 else np.zeros_like(v)
