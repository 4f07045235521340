"""Principal component analysis of flattened shapes (used for expressions and identities)."""
from __future__ import annotations

import numpy as np

from workers.faces.blas import single_threaded


@single_threaded()
def fit_pca(
    samples: np.ndarray, variance: float = 0.998, max_components: int = 60
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """PCA of (M, D) samples: ``(mean (D,), basis (D, K), variances (K,), total_variance)``.

    K is the smallest count whose cumulative explained variance reaches ``variance`` (0-1],
    capped by ``max_components`` and the data's rank. Each basis vector's sign is fixed so that
    its largest-magnitude entry is positive (the fit is then deterministic).
    """
    data = np.asarray(samples, dtype=np.float64)
    if data.ndim != 2 or len(data) < 2:
        raise ValueError("PCA needs at least two samples as an (M, D) array")
    mean = data.mean(axis=0)
    centred = data - mean
    # Eigen-decompose the small (M, M) Gram matrix instead of an SVD of (M, 3N): same
    # components, several times faster when D >> M (the usual case for meshes).
    gram_eig, gram_vec = np.linalg.eigh(centred @ centred.T)
    order = np.argsort(gram_eig)[::-1]
    gram_eig, gram_vec = np.clip(gram_eig[order], 0.0, None), gram_vec[:, order]
    eig = gram_eig / (len(data) - 1)
    total = float(eig.sum())
    rank = int(np.sum(eig > max(total, np.finfo(float).tiny) * 1e-12))
    cumulative = np.cumsum(eig) / total if total > 0 else np.ones_like(eig)
    k = int(np.searchsorted(cumulative, variance - 1e-12) + 1)
    k = max(1, min(k, max_components, max(rank, 1)))
    basis = centred.T @ (gram_vec[:, :k] / np.sqrt(np.maximum(gram_eig[:k], np.finfo(float).tiny)))
    basis, _ = np.linalg.qr(basis)  # removes the rounding the Gram route leaves in the orthogonality
    signs = np.sign(basis[np.abs(basis).argmax(axis=0), np.arange(k)])
    basis *= np.where(signs == 0, 1.0, signs)
    return mean, basis, eig[:k].copy(), total
