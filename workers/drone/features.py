"""Feature points: FAST corners (the paper's detector) and SIFT (the paper's comparison)."""
from __future__ import annotations

import cv2
import numpy as np


def fast_corners(gray: np.ndarray, threshold: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """All FAST-9 corners with non-maximum suppression.

    gray: (H, W) uint8. Returns points (N, 2) float32 pixel centres (x, y) and responses (N,)
    float32, strongest first.
    """
    det = cv2.FastFeatureDetector_create(threshold=int(threshold), nonmaxSuppression=True)
    kps = det.detect(gray, None)
    if not kps:
        return np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
    pts = cv2.KeyPoint_convert(kps).reshape(-1, 2)  # in C++: a list of tuples costs ~3x the detection
    resp = np.fromiter((k.response for k in kps), np.float32, len(kps))
    order = np.argsort(-resp, kind="stable")
    return pts[order], resp[order]


def fast_corners_adaptive(gray: np.ndarray, threshold: int, min_count: int) -> np.ndarray:
    """FAST corners (N, 2) float32, strongest first, lowering the threshold from ``threshold``
    by halves (not below 5) until at least ``min_count`` are found: low-contrast footage (haze,
    blur, a cheap sensor) gets enough corners without flooding sharp footage with weak ones."""
    t = int(threshold)
    while True:
        pts, _ = fast_corners(gray, t)
        if len(pts) >= min_count or t <= 5:
            return pts
        t = max(5, t // 2)


def spread(points: np.ndarray, cell: float, limit: int, occupied: np.ndarray | None = None,
           shape: tuple[int, int] | None = None) -> np.ndarray:
    """Indices of at most one point per ``cell``-pixel grid cell, first come first kept.

    points: (N, 2) float32 in priority order (strongest first); ``occupied`` (M, 2) points
    whose cells are already taken; ``shape`` (H, W) of the image (default: from the points).
    Returns at most ``limit`` indices (int64) into ``points``.
    """
    if len(points) == 0 or limit <= 0:
        return np.zeros(0, np.int64)
    if shape is None:
        shape = (int(points[:, 1].max()) + 1, int(points[:, 0].max()) + 1)
    ncol = int(np.ceil(shape[1] / cell)) + 1

    def cells(p: np.ndarray) -> np.ndarray:
        g = np.floor(p / cell).astype(np.int64)
        return g[:, 1] * ncol + g[:, 0]

    ids = cells(points)
    _, first = np.unique(ids, return_index=True)
    first = np.sort(first)
    if occupied is not None and len(occupied):
        first = first[~np.isin(ids[first], cells(occupied))]
    return first[:limit]


SIFT_OFFSET_PX = 0.25
"""How far OpenCV's SIFT reports a keypoint right of and below where it lies (OpenCV 4.x): its first octave is the
image upsampled twice with pixel centres aligned (x_up = 2 x + 0.5), but it maps positions back as x_up / 2. A blob
drawn at a known sub-pixel centre comes back 0.25 px off in x and y at every octave. Left in, the offset is the
same in every photo's own axes, so photos of two flight lines flown in opposite directions see each other's points
0.5 px apart: on the synthetic survey that bent the self-calibrated focal length by 1.3 % and lifted the ground
by 1.8 m (test_matching's blob test holds the correction)."""


def sift_features(gray: np.ndarray, max_features: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    """SIFT keypoints (N, 2) float32 (x, y) pixels, pixel centres at integers (as FAST and the optical flow
    give them), and descriptors (N, 128) float32 of gray (H, W) uint8."""
    sift = cv2.SIFT_create(nfeatures=int(max_features))
    kps, desc = sift.detectAndCompute(gray, None)
    if desc is None or not kps:
        return np.zeros((0, 2), np.float32), np.zeros((0, 128), np.float32)
    return np.array([k.pt for k in kps], np.float32) - SIFT_OFFSET_PX, desc.astype(np.float32)
