"""Silhouettes by background subtraction (the paper's III-D, first step of each frame)."""
from __future__ import annotations

import cv2
import numpy as np


def silhouette_from_background(
    image: np.ndarray, background: np.ndarray, threshold: float = 20.0, clean_px: int = 2,
) -> np.ndarray:
    """Foreground mask of ``image`` against the empty-scene ``background``.

    image, background: (H, W, 3) uint8 BGR. A pixel is foreground when its largest channel difference
    exceeds ``threshold`` (0..255). A morphological opening then closing with a disk of radius
    ``clean_px`` removes speckle and fills pinholes. Returns (H, W) bool.
    """
    if image.shape != background.shape:
        raise ValueError(f"image {image.shape} and background {background.shape} differ in shape")
    d = cv2.absdiff(image, background)
    diff = np.maximum(np.maximum(d[..., 0], d[..., 1]), d[..., 2])  # d.max(axis=2) is ~25x slower
    mask = (diff > threshold).view(np.uint8)
    if clean_px > 0:
        disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * clean_px + 1, 2 * clean_px + 1))
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, disk)
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, disk)
    return mask.astype(bool)


def dilate(mask: np.ndarray, px: int) -> np.ndarray:
    """(H, W) bool mask grown by ``px`` pixels (a square): a conservative hull tolerates
    silhouette and calibration errors of that size."""
    if px <= 0:
        return mask.astype(bool)
    k = np.ones((2 * px + 1, 2 * px + 1), np.uint8)
    return cv2.dilate(mask.astype(np.uint8), k).astype(bool)
