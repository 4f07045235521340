"""Image-quality measures for rendered views: PSNR, SSIM, a blur measure and frame-to-frame jumps.

All take uint8 (H, W, 3) BGR images (or float arrays in 0..255) and an optional (H, W) bool mask
of the pixels to score.
"""
from __future__ import annotations

import cv2
import numpy as np


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Peak signal-to-noise ratio in dB over ``mask`` (all pixels when None); inf when equal."""
    d = a.astype(np.float64) - b.astype(np.float64)
    d = d[mask] if mask is not None else d
    mse = float(np.mean(d * d)) if d.size else float("nan")
    return float("inf") if mse == 0 else 10.0 * np.log10(255.0**2 / mse)


def ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None, sigma: float = 1.5) -> float:
    """Mean structural similarity (Wang et al. 2004; Gaussian window, sigma 1.5, K1 0.01, K2 0.03)
    of the luma of ``a`` and ``b``, averaged over ``mask`` (all pixels when None)."""
    x = _luma(a)
    y = _luma(b)
    c1 = (0.01 * 255) ** 2
    c2 = (0.03 * 255) ** 2

    def blur(img: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(img, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)

    mx, my = blur(x), blur(y)
    vx = blur(x * x) - mx * mx
    vy = blur(y * y) - my * my
    cxy = blur(x * y) - mx * my
    s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    return float(s[mask].mean() if mask is not None else s.mean())


def highfreq_ratio(img: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Blur measure: energy of the Laplacian of ``img``'s luma over that of ``ref`` (inside
    ``mask``, eroded by 2 px so that the mask edge itself does not count). 1 = as sharp as the
    reference; below 1 = blurred."""
    if mask is not None:
        mask = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    li = cv2.Laplacian(_luma(img), cv2.CV_64F)
    lr = cv2.Laplacian(_luma(ref), cv2.CV_64F)
    ei = np.mean((li[mask] if mask is not None else li) ** 2)
    er = np.mean((lr[mask] if mask is not None else lr) ** 2)
    return float(ei / er) if er > 0 else float("nan")


def frame_jump(prev: np.ndarray, cur: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean absolute colour change (0..255) between consecutive frames over ``mask``."""
    d = np.abs(cur.astype(np.float64) - prev.astype(np.float64)).mean(axis=2)
    return float(d[mask].mean() if mask is not None else d.mean())


def _luma(img: np.ndarray) -> np.ndarray:
    img = np.asarray(img, np.float64)
    if img.ndim == 2:
        return img
    return 0.114 * img[..., 0] + 0.587 * img[..., 1] + 0.299 * img[..., 2]
