"""Estimating a person's neutral face ``X_neutral`` (eq. 6) when only a face with an expression is given.

The paper always has the person's neutral scan. A user of the service often uploads just one
mesh; taking the mean neutral face then charges the person's identity to the expression
parameters. Instead we fit, jointly and under Gaussian priors from the training set, an identity
PCA of the training neutral faces (``X_neutral = X_mean + B a``) and the expression model
(``S = S_bar + U f``)::

    x - X_mean - S_bar = B a + U f + noise,   a ~ N(0, diag nu), f ~ N(0, diag lambda)

and keep ``X_mean + B a`` (the MAP estimate) as the neutral face.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.faces.morphable import MorphableModel
from workers.faces.pca import fit_pca


@dataclass(frozen=True, eq=False)
class IdentityModel:
    """PCA of the training people's neutral faces around the morphable model's mean neutral face.

    ``basis``: (3N, J) orthonormal; ``variances``: (J,); ``cross``: (J, K) ``B^T U`` against the
    expression basis; ``noise_var``: per-coordinate variance neither basis explains (mesh units^2).
    """

    basis: np.ndarray
    variances: np.ndarray
    cross: np.ndarray
    noise_var: float


def identity_model(neutrals: np.ndarray, morph: MorphableModel, variance: float = 0.998,
                   max_components: int = 60) -> IdentityModel:
    """Identity PCA of (P, N, 3) neutral faces (P >= 2) for the expression model ``morph``."""
    flat = np.asarray(neutrals, dtype=np.float64).reshape(len(neutrals), -1)
    _, basis, variances, total = fit_pca(flat, variance, max_components)
    left_out = (total - variances.sum()) + (morph.total_variance - morph.variances.sum())
    floor = 1e-6 * (total + morph.total_variance) / flat.shape[1]  # keeps the solve regular
    noise = max(left_out / flat.shape[1], floor, np.finfo(float).tiny)
    return IdentityModel(basis, variances, basis.T @ morph.basis, float(noise))


def estimate_neutral(morph: MorphableModel, identity: IdentityModel, vertices: np.ndarray) -> np.ndarray:
    """(N, 3) MAP estimate of the neutral face of the person in the (N, 3) face ``vertices``."""
    r = np.asarray(vertices, dtype=np.float64).ravel() - morph.neutral.ravel() - morph.mean
    j, k = identity.basis.shape[1], morph.n_components
    gram = np.eye(j + k)
    gram[:j, j:] = identity.cross
    gram[j:, :j] = identity.cross.T
    prior = np.concatenate([identity.variances, morph.variances])
    gram[np.diag_indices(j + k)] += identity.noise_var / np.maximum(prior, np.finfo(float).tiny)
    coeffs = np.linalg.solve(gram, np.concatenate([identity.basis.T @ r, morph.basis.T @ r]))
    return morph.neutral + (identity.basis @ coeffs[:j]).reshape(-1, 3)
