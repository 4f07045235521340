"""Quality measures: PSNR, SSIM (Gaussian window), depth error, and the band around depth edges.

Masks are (H, W) bool; a masked score uses only the pixels where the mask is True.
"""
from __future__ import annotations

import cv2
import numpy as np

from .errors import DepthInputError

SSIM_SIGMA = 1.5
SSIM_K1, SSIM_K2 = 0.01, 0.03


def _check_pair(a: np.ndarray, b: np.ndarray) -> None:
    if a.shape != b.shape:
        raise DepthInputError(f"images differ in shape: {a.shape} vs {b.shape}")


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None, peak: float = 255.0) -> float:
    """PSNR in dB over all channels of two images (H, W[, C]) of equal shape; inf when identical."""
    _check_pair(a, b)
    err = (a.astype(np.float64) - b.astype(np.float64)) ** 2
    if err.ndim == 3:
        err = err.mean(axis=2)
    if mask is not None:
        err = err[mask]
    if err.size == 0:
        return float("nan")
    mse = float(err.mean())
    return float("inf") if mse == 0 else 10.0 * np.log10(peak**2 / mse)


def ssim_map(a: np.ndarray, b: np.ndarray, peak: float = 255.0) -> np.ndarray:
    """SSIM map (H, W) float64 of the luma of two images (BGR (H, W, 3) or grey (H, W)).

    Wang et al. 2004 with an 11x11 Gaussian window (sigma 1.5), K1 = 0.01, K2 = 0.03.
    """
    _check_pair(a, b)
    x, y = _luma(a), _luma(b)
    c1, c2 = (SSIM_K1 * peak) ** 2, (SSIM_K2 * peak) ** 2

    def blur(img: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(img, (11, 11), SSIM_SIGMA, borderType=cv2.BORDER_REFLECT)

    mx, my = blur(x), blur(y)
    vx, vy, cxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
    return ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))


def ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None, peak: float = 255.0) -> float:
    """Mean SSIM of the luma (see :func:`ssim_map`), over ``mask`` when given."""
    m = ssim_map(a, b, peak)
    vals = m if mask is None else m[mask]
    return float(vals.mean()) if vals.size else float("nan")


def _luma(img: np.ndarray) -> np.ndarray:
    img = img.astype(np.float64)
    if img.ndim == 3:
        return img[..., 0] * 0.114 + img[..., 1] * 0.587 + img[..., 2] * 0.299
    return img


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
