"""The morphable 3D face model (the paper's II): a displacement PCA over one topology.

Displacements ``S = X - X_neutral`` (eq. 1) are flattened to (3N,) vectors (x0, y0, z0, x1, ...).
PCA gives the mean displacement ``S_bar`` and orthonormal eigenvectors ``U_k``; a face's
parameters are ``f_k = U_k . (S - S_bar)`` (eqs. 2 and 7) and parameters map back to a face with
``X = X_neutral + S_bar + sum_k f_k U_k`` (eqs. 3 and 9).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.faces.mesh import Mesh


@dataclass(frozen=True, eq=False)
class MorphableModel:
    """Displacement PCA of registered faces sharing one topology.

    ``neutral``: (N, 3) float64, the mean neutral face (the default ``X_neutral``);
    ``mean``: (3N,) ``S_bar``; ``basis``: (3N, K) orthonormal columns ``U_k``;
    ``variances``: (K,) eigenvalues, descending; ``total_variance``: the sum of all eigenvalues
    (so that ``variances / total_variance`` is the explained ratio); ``topology``: the faces.
    """

    neutral: np.ndarray
    mean: np.ndarray
    basis: np.ndarray
    variances: np.ndarray
    total_variance: float
    topology: Mesh

    @property
    def n_components(self) -> int:
        return self.basis.shape[1]

    @property
    def n_vertices(self) -> int:
        return len(self.neutral)

    def explained_ratio(self) -> float:
        """Fraction of the training displacements' variance the K components keep."""
        return float(self.variances.sum() / self.total_variance) if self.total_variance > 0 else 1.0

    def project(self, displacement: np.ndarray) -> np.ndarray:
        """Eq. 7: (K,) parameters of one (N, 3) or (3N,) displacement ``S``; (B, K) for (B, N, 3) or (B, 3N)."""
        s = np.asarray(displacement, dtype=np.float64)
        f = (s.reshape(-1, self.mean.size) - self.mean) @ self.basis
        return f[0] if s.size == self.mean.size else f

    def displacement(self, f: np.ndarray) -> np.ndarray:
        """Eq. 3: the (N, 3) displacement ``S_bar + sum_k f_k U_k`` of (K,) parameters."""
        return (self.mean + self.basis @ np.asarray(f, dtype=np.float64)).reshape(-1, 3)

    def reconstruct(self, f: np.ndarray, neutral: np.ndarray | None = None) -> np.ndarray:
        """Eq. 9: (N, 3) face ``X_neutral + S_bar + sum_k f_k U_k`` (default: the mean neutral)."""
        base = self.neutral if neutral is None else np.asarray(neutral, dtype=np.float64)
        return base + self.displacement(f)

    def mahalanobis(self, f: np.ndarray) -> np.ndarray:
        """Mahalanobis distance of (..., K) parameters from the training mean: ``sqrt(sum f_k^2 / lambda_k)``."""
        f = np.asarray(f, dtype=np.float64)
        return np.sqrt(np.sum(f * f / np.maximum(self.variances, np.finfo(float).tiny), axis=-1))
