"""The straightforward plane sweep: per plane and camera one ``cv2.warpPerspective`` of the whole
image by the plane-induced homography, then the variance across cameras in numpy.

It makes the same choice as :func:`workers.sweep.kernels.sweep_depth` without visual hull (same
planes, same voting rule, same cost, ties to the nearer plane) and serves as the baseline for the
kernel's speed and as an independent check of its geometry.
"""
from __future__ import annotations

import cv2
import numpy as np

from workers.camera import Camera


def plane_homographies(cameras: list[Camera], virtual: Camera, depth: float) -> np.ndarray:
    """Homographies (N, 3, 3) mapping virtual pixels (u, v, 1) to each camera's pixels for the plane
    at ``depth`` (metres along the virtual axis, parallel to the virtual image plane)."""
    G = virtual.R.T @ np.linalg.inv(virtual.K)
    e3 = np.array([0.0, 0.0, 1.0])
    out = []
    for c in cameras:
        M, p = c.P[:, :3], c.P[:, 3]
        out.append(M @ G + np.outer(M @ virtual.center + p, e3) / depth)
    return np.stack(out)


def reference_sweep(
    cameras: list[Camera], images: list[np.ndarray], virtual: Camera, depths: np.ndarray, min_views: int = 2,
    warp_dtype: type = np.float32,
) -> tuple[np.ndarray, np.ndarray]:
    """Best plane index (h, w) int32 (-1 where fewer than ``min_views`` cameras ever see the point)
    and its cost (h, w) float32 (variance summed over B, G, R).

    cameras/images: the rig (uint8 (H, W, 3) BGR each, no distortion); depths (P,) plane depths.
    A camera votes where all four bilinear taps lie inside its image (warped validity mask = 1).
    warp_dtype: the image type handed to OpenCV (float32: exact bilinear; uint8: OpenCV's faster
    fixed-point interpolation).
    """
    h, w = virtual.height, virtual.width
    srcs = [img.astype(warp_dtype) for img in images]
    ones = [np.ones(img.shape[:2], np.float32) for img in images]
    best = np.full((h, w), -1, np.int32)
    best_cost = np.full((h, w), np.inf, np.float32)
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    for j, z in enumerate(depths):
        Hs = plane_homographies(cameras, virtual, float(z))
        total = np.zeros((h, w, 3), np.float64)  # float64: exact zeros on uniform areas, no spurious ties
        total_sq = np.zeros((h, w), np.float64)
        count = np.zeros((h, w), np.float32)
        for H, src, one in zip(Hs, srcs, ones):
            warped = cv2.warpPerspective(src, H, (w, h), flags=flags, borderMode=cv2.BORDER_CONSTANT).astype(np.float32)
            valid = cv2.warpPerspective(one, H, (w, h), flags=flags, borderMode=cv2.BORDER_CONSTANT) >= 1.0 - 1e-6
            warped[~valid] = 0
            total += warped
            total_sq += (warped * warped).sum(axis=2)
            count += valid
        with np.errstate(divide="ignore", invalid="ignore"):
            cost = (total_sq - (total * total).sum(axis=2) / count) / count
        cost[count < min_views] = np.inf
        better = cost < best_cost
        best[better] = j
        best_cost[better] = cost[better]
    return best, best_cost
