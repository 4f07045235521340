"""Measures of rendered views beside PSNR/SSIM (:mod:`workers.common.imagemetrics`): blur and frame-to-frame jumps.

All take uint8 (H, W, 3) BGR images (or float arrays in 0..255) and an optional (H, W) bool mask
of the pixels to score.
"""
from __future__ import annotations

import cv2
import numpy as np

from workers.common.imagemetrics import luma


def highfreq_ratio(img: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Blur measure: energy of the Laplacian of ``img``'s luma over that of ``ref`` (inside
    ``mask``, eroded by 2 px so that the mask edge itself does not count). 1 = as sharp as the
    reference; below 1 = blurred."""
    if mask is not None:
        mask = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    li = cv2.Laplacian(luma(img), cv2.CV_64F)
    lr = cv2.Laplacian(luma(ref), cv2.CV_64F)
    ei = np.mean((li[mask] if mask is not None else li) ** 2)
    er = np.mean((lr[mask] if mask is not None else lr) ** 2)
    return float(ei / er) if er > 0 else float("nan")


def frame_jump(prev: np.ndarray, cur: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean absolute colour change (0..255) between consecutive frames over ``mask``."""
    d = np.abs(cur.astype(np.float64) - prev.astype(np.float64)).mean(axis=2)
    return float(d[mask].mean() if mask is not None else d.mean())
