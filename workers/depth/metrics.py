"""Depth quality measures: depth error and the band around depth edges (image PSNR/SSIM: :mod:`workers.common.imagemetrics`).

Masks are (H, W) bool; a masked score uses only the pixels where the mask is True.
"""
from __future__ import annotations

import cv2
import numpy as np

from .errors import DepthInputError


def _check_pair(a: np.ndarray, b: np.ndarray) -> None:
    if a.shape != b.shape:
        raise DepthInputError(f"images differ in shape: {a.shape} vs {b.shape}")


def depth_errors(
    estimate: np.ndarray, truth: np.ndarray, valid: np.ndarray | None = None, bad_threshold: float = 1.0,
    mask: np.ndarray | None = None,
) -> dict[str, float]:
    """Mean absolute error and bad-pixel rate of a depth/disparity map against the truth.

    estimate, truth: (H, W) in the same unit (e.g. disparity pixels). valid: where truth is known.
    bad_threshold: an error above it makes a pixel bad. Returns {"mae", "bad_rate", "pixels"}.
    """
    _check_pair(estimate, truth)
    use = np.ones(truth.shape, bool) if valid is None else valid.copy()
    if mask is not None:
        use &= mask
    err = np.abs(estimate.astype(np.float64) - truth.astype(np.float64))[use]
    if err.size == 0:
        return {"mae": float("nan"), "bad_rate": float("nan"), "pixels": 0}
    return {"mae": float(err.mean()), "bad_rate": float((err > bad_threshold).mean()), "pixels": int(err.size)}


def edge_band(depth: np.ndarray, jump: float, radius: int, valid: np.ndarray | None = None) -> np.ndarray:
    """Pixels within ``radius`` of a depth edge: (H, W) bool.

    depth: (H, W) float. An edge is a pixel whose 3x3 neighbourhood spans more than ``jump``
    (same unit as depth); unknown pixels (``valid`` False) never make edges.
    """
    d = depth.astype(np.float32)
    if valid is not None:
        lo = np.where(valid, d, np.inf).astype(np.float32)
        hi = np.where(valid, d, -np.inf).astype(np.float32)
    else:
        lo = hi = d
    k3 = np.ones((3, 3), np.uint8)
    with np.errstate(over="ignore", invalid="ignore"):  # windows with no known pixel give -inf/nan
        span = cv2.dilate(hi, k3) - cv2.erode(lo, k3)
    edges = (np.isfinite(span) & (span > jump)).astype(np.uint8)
    kb = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    return cv2.dilate(edges, kb) > 0
