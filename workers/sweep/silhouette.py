"""Silhouettes by background subtraction (the paper's III-D, first step of each frame)."""
from __future__ import annotations

import cv2
import numpy as np


BG_THRESHOLD = 20.0  # largest channel difference (0..255) from the empty scene that still counts as background
CLEAN_PX = 2  # radius of the disk that cleans a silhouette (opening, then closing)
HULL_DILATE_PX = 2  # margin added around each silhouette before it culls the visual hull


def cleaning_disk(clean_px: int = CLEAN_PX) -> np.ndarray:
    """The structuring element of the cleaning: (2 clean_px + 1)^2 uint8, OpenCV's ellipse (1 inside)."""
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * clean_px + 1, 2 * clean_px + 1))


def silhouette_from_background(
    image: np.ndarray, background: np.ndarray, threshold: float = BG_THRESHOLD, clean_px: int = CLEAN_PX,
) -> np.ndarray:
    """Foreground mask of ``image`` against the empty-scene ``background``.

    image, background: (H, W, 3) uint8 BGR. A pixel is foreground when its largest channel difference
    exceeds ``threshold`` (0..255). A morphological opening then closing with a disk of radius
    ``clean_px`` removes speckle and fills pinholes. Returns (H, W) bool.
    """
    if image.shape != background.shape:
        raise ValueError(f"image {image.shape} and background {background.shape} differ in shape")
    h, w = image.shape[:2]
    if threshold < 0 or threshold >= 255:  # every pixel, or none (differences are integers 0..255)
        mask = np.full((h, w), 1 if threshold < 0 else 0, np.uint8)
    else:
        mask = _foreground(image, background, int(threshold))
    if clean_px > 0:
        disk = cleaning_disk(clean_px)
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, disk)
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, disk)
    return mask.astype(bool)


def _foreground(image: np.ndarray, background: np.ndarray, threshold: int) -> np.ndarray:
    """(H, W) uint8, 255 where the largest channel difference of ``image`` and ``background`` ((H, W, 3)
    uint8) exceeds ``threshold`` (an integer: for integer differences d > t equals d > floor(t)), else 0.
    OpenCV's vectorised single-threaded passes: a live rig calls this for every camera of every frame
    set, and a parallel numba kernel on an image this small spends more CPU starting and parking its
    threads than comparing, the more so the busier the machine."""
    diff = cv2.absdiff(np.ascontiguousarray(image), np.ascontiguousarray(background))
    b, g, r = cv2.split(diff)
    return cv2.compare(cv2.max(cv2.max(b, g), r), threshold, cv2.CMP_GT)


def dilate(mask: np.ndarray, px: int) -> np.ndarray:
    """(H, W) bool mask grown by ``px`` pixels (a square): a conservative hull tolerates
    silhouette and calibration errors of that size."""
    if px <= 0:
        return mask.astype(bool)
    k = np.ones((2 * px + 1, 2 * px + 1), np.uint8)
    return cv2.dilate(mask.astype(np.uint8), k).astype(bool)


def silhouette_box(mask: np.ndarray) -> tuple[float, float, float, float]:
    """Bounding box (u0, u1, v0, v1) in px of the non-zero pixels of ``mask`` (H, W), widened by half a
    pixel on every side (the points that a nearest-pixel lookup maps into it); u0 > u1 when empty."""
    cols = np.flatnonzero(mask.any(axis=0))
    if cols.size == 0:
        return 1.0, -1.0, 1.0, -1.0
    rows = np.flatnonzero(mask.any(axis=1))
    return cols[0] - 0.5, cols[-1] + 0.5, rows[0] - 0.5, rows[-1] + 0.5
