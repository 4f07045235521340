"""Transforming a face (eqs. 6-9): project, move along an impression transfer vector, reconstruct.

``Q`` is given in units of the model's ``q_unit`` (the RMS size of a training expression), so
``Q = 1`` moves the face by as much as a typical expression differs from a neutral face; in the
paper's notation ``f' = f + (Q * q_unit) * w``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from workers.faces.blas import single_threaded
from workers.faces.errors import FaceInputError
from workers.faces.mesh import Mesh, check_finite, check_topology
from workers.faces.model import FaceModel
from workers.faces.neutral import estimate_neutral as estimate_neutral_face
from workers.faces.transfer import apply_transfer

METHODS = ("svm", "fisher")
Q_LIMIT = 3.0
MAX_NEIGHBOURS = 100


@dataclass(frozen=True, eq=False)
class TransformResult:
    """A transformed face and what happened to it.

    ``vertices``: (N, 3) float64 output; ``scores`` / ``new_scores``: (K,) ``f`` and ``f'``;
    ``direction``: the unit (K,) transfer vector used; ``decision_before`` / ``decision_after``:
    the impression's SVC decision values of ``f`` and ``f'`` (> 0: on the impression's side);
    ``mahalanobis_before`` / ``_after``: distances from the training mean in the PCA space;
    ``max_displacement``: the largest vertex move (mesh units); ``residual_rms``: RMS per-vertex
    distance between the input displacement and its K-component projection (large values mean
    the mesh is not registered like the training faces); ``neutral_source``: where ``X_neutral``
    came from: ``"given"``, ``"estimated"`` or ``"mean"``.
    """

    vertices: np.ndarray
    scores: np.ndarray
    new_scores: np.ndarray
    direction: np.ndarray
    decision_before: float
    decision_after: float
    mahalanobis_before: float
    mahalanobis_after: float
    max_displacement: float
    residual_rms: float
    neutral_source: str

    def info(self) -> dict[str, Any]:
        """The scalar facts as a JSON-able dict."""
        return {
            "decision_before": round(self.decision_before, 6),
            "decision_after": round(self.decision_after, 6),
            "mahalanobis_before": round(self.mahalanobis_before, 6),
            "mahalanobis_after": round(self.mahalanobis_after, 6),
            "max_displacement": round(self.max_displacement, 6),
            "residual_rms": round(self.residual_rms, 6),
            "neutral_source": self.neutral_source,
        }


def check_request(model: FaceModel, impression: str, method: str, q: float,
                  m: int | None = None, n: int | None = None) -> int:
    """Validate a transform request; the impression's index. Raises FaceInputError."""
    index = model.impression_index(impression)
    if method not in METHODS:
        raise FaceInputError(f"unknown method {method!r}; use one of: {', '.join(METHODS)}")
    try:
        q_value = float(q)
    except (TypeError, ValueError):
        q_value = math.nan
    if not math.isfinite(q_value) or abs(q_value) > Q_LIMIT:
        raise FaceInputError(f"Q must be a number between {-Q_LIMIT:g} and {Q_LIMIT:g}; got {q!r}")
    for name, value in (("m", m), ("n", n)):
        is_int = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
        if value is not None and not (is_int and 1 <= value <= MAX_NEIGHBOURS):
            raise FaceInputError(f"{name} must be an integer from 1 to {MAX_NEIGHBOURS}; got {value!r}")
    return index


def transfer_direction(model: FaceModel, index: int, method: str, f: np.ndarray,
                       m: int | None = None, n: int | None = None) -> np.ndarray:
    """Unit (K,) transfer vector: the impression's Fisher ``e``, or the SVM ``w`` of eq. 5 for ``f``."""
    if method == "fisher":
        return model.fisher[index]
    return model.svms[index].direction(f, m or model.m, n or model.n)


@single_threaded()
def transform_vertices(
    model: FaceModel, vertices: np.ndarray, impression: str, method: str = "svm", q: float = 1.0, *,
    neutral: np.ndarray | None = None, estimate_neutral: bool = True, m: int | None = None,
    n: int | None = None, keep_detail: bool = True,
) -> TransformResult:
    """Eqs. 6-9 on an (N, 3) face registered to the model.

    ``neutral``: the same person's (N, 3) neutral face ``X_neutral``. Without it, the neutral face
    is estimated from the input (:mod:`workers.faces.neutral`) when ``estimate_neutral`` and the
    model has an identity model, else the model's mean neutral face is used. ``keep_detail``: add
    back the part of ``S`` the K components do not represent (identity and fine detail when the
    neutral face is not the person's), which makes the output ``X + U (f' - f)`` and Q = 0 exactly
    the input; False gives eq. 9 as written.
    """
    index = check_request(model, impression, method, q, m, n)
    morph = model.morph
    x = np.asarray(vertices, dtype=np.float64)
    if x.shape != morph.neutral.shape or (neutral is not None and np.shape(neutral) != x.shape):
        raise FaceInputError(f"expected ({morph.n_vertices}, 3) vertices, got {x.shape}")
    base, source = _neutral_face(model, x, neutral, estimate_neutral)
    s = (x - base).ravel()  # eq. 6
    f = morph.project(s)  # eq. 7
    direction = transfer_direction(model, index, method, f, m, n)
    f_new = apply_transfer(f, direction, float(q) * model.q_unit)  # eq. 8
    # |S - S_bar - U f|^2 = |S - S_bar|^2 - |f|^2 for orthonormal U: no third pass over the basis.
    residual2 = max(float(np.sum((s - morph.mean) ** 2) - f @ f), 0.0)
    if keep_detail:
        out = x + (morph.basis @ (f_new - f)).reshape(-1, 3)
    else:
        out = morph.reconstruct(f_new, base)  # eq. 9
    svm = model.svms[index]
    return TransformResult(
        vertices=out, scores=f, new_scores=f_new, direction=direction,
        decision_before=float(svm.decision(f)), decision_after=float(svm.decision(f_new)),
        mahalanobis_before=float(morph.mahalanobis(f)), mahalanobis_after=float(morph.mahalanobis(f_new)),
        max_displacement=float(np.linalg.norm(out - x, axis=1).max()),
        residual_rms=float(np.sqrt(residual2 / morph.n_vertices)),
        neutral_source=source,
    )


def _neutral_face(model: FaceModel, x: np.ndarray, neutral: np.ndarray | None,
                  estimate: bool) -> tuple[np.ndarray, str]:
    """``X_neutral`` (N, 3) for the face ``x`` and where it came from."""
    if neutral is not None:
        return np.asarray(neutral, dtype=np.float64), "given"
    if estimate and model.identity is not None:
        return estimate_neutral_face(model.morph, model.identity, x), "estimated"
    return model.morph.neutral, "mean"


def transform_mesh(
    model: FaceModel, mesh: Mesh, impression: str, method: str = "svm", q: float = 1.0, *,
    neutral: Mesh | None = None, estimate_neutral: bool = True, m: int | None = None, n: int | None = None,
    keep_detail: bool = True,
) -> tuple[Mesh, TransformResult]:
    """:func:`transform_vertices` on a mesh after checking its topology and coordinates."""
    for candidate, what in ((mesh, "mesh"), (neutral, "neutral mesh")):
        if candidate is None:
            continue
        try:
            check_topology(candidate, model.morph.topology)
            check_finite(candidate)
        except FaceInputError as exc:
            raise FaceInputError(f"{what}: {exc}") from None
    result = transform_vertices(model, mesh.vertices, impression, method, q,
                                neutral=None if neutral is None else neutral.vertices,
                                estimate_neutral=estimate_neutral, m=m, n=n, keep_detail=keep_detail)
    return mesh.with_vertices(result.vertices), result
