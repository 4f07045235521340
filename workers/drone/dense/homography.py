"""The plane-induced homographies of the sweep, and the plain-numpy resampling they define."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .views import View


def sweep_geometry(ref: View, others: Sequence[View]) -> tuple[np.ndarray, np.ndarray]:
    """The plane-induced homographies of ``others`` seen from ``ref``: Q (N, 3, 3), B (N, 3) float64.

    Reference pixel (x, y) at inverse depth s (1/z, z along the reference's optical axis) appears in view
    i at the homogeneous pixel ``Q[i] @ (x, y, 1) + s * B[i]``; ``Q[i] = K_i R_i R_ref^T K_ref^-1`` and
    ``B[i] = K_i (R_i C_ref + t_i)`` (the renderer's form, :mod:`workers.sweep.kernels`)."""
    G = ref.camera.R.T @ np.linalg.inv(ref.camera.K)
    C = ref.camera.center
    cams = [o.camera for o in others]
    Q = np.stack([c.K @ c.R @ G for c in cams]) if cams else np.zeros((0, 3, 3))
    B = np.stack([c.K @ (c.R @ C + c.t) for c in cams]) if cams else np.zeros((0, 3))
    return np.ascontiguousarray(Q, np.float64), np.ascontiguousarray(B, np.float64)


def plane_samples(image: np.ndarray, Q: np.ndarray, B: np.ndarray, s: float, h: int, w: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """One view's grey image (H, W) float32 resampled into an h x w reference for the plane at inverse
    depth ``s``: (h, w) float32 samples (bilinear, positions clamped to the image) and (h, w) bool, True
    where the point is in front of the view and inside its image. Plain numpy: the definition the
    compiled sweep (:func:`.sweep.zncc_sweep`) reproduces, for tests."""
    Hn, Wn = image.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    hx = Q[0, 0] * xs + Q[0, 1] * ys + Q[0, 2] + s * B[0]
    hy = Q[1, 0] * xs + Q[1, 1] * ys + Q[1, 2] + s * B[1]
    hz = Q[2, 0] * xs + Q[2, 1] * ys + Q[2, 2] + s * B[2]
    front = hz > 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(front, hx / np.where(front, hz, 1.0), 0.0)
        v = np.where(front, hy / np.where(front, hz, 1.0), 0.0)
    ok = front & (u >= 0) & (u <= Wn - 1) & (v >= 0) & (v <= Hn - 1)
    uc = np.clip(u, 0, Wn - 1)
    vc = np.clip(v, 0, Hn - 1)
    ix = np.minimum(uc.astype(np.int64), max(Wn - 2, 0))
    iy = np.minimum(vc.astype(np.int64), max(Hn - 2, 0))
    fx, fy = uc - ix, vc - iy
    img = image.astype(np.float64)
    x1, y1 = np.minimum(ix + 1, Wn - 1), np.minimum(iy + 1, Hn - 1)
    top = img[iy, ix] * (1 - fx) + img[iy, x1] * fx
    bot = img[y1, ix] * (1 - fx) + img[y1, x1] * fx
    return (top * (1 - fy) + bot * fy).astype(np.float32), ok
