"""Lens distortion undone once per frame, before any sweep sees the pixels (same K: the undistorted image is
the pinhole camera's ``K [R | t]``)."""
from __future__ import annotations

import cv2
import numpy as np

from workers.camera import Camera

Maps = tuple[np.ndarray, np.ndarray]


def undistort_maps(cam: Camera) -> Maps | None:
    """The remap tables (two (H, W) float32, source x and y in px) that undistort ``cam``'s images into its
    pinhole model with the same K; None when the camera has no distortion."""
    if not cam.has_distortion:
        return None
    return cv2.initUndistortRectifyMap(cam.K, cam.dist, None, cam.K, (cam.width, cam.height), cv2.CV_32FC1)


def undistorted(maps: Maps | None, image: np.ndarray, nearest: bool = False) -> np.ndarray:
    """``image`` (H, W[, C]) through ``maps`` (bilinear, or nearest for masks; black outside); itself for None."""
    if maps is None:
        return image
    interp = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
    return cv2.remap(image, maps[0], maps[1], interp, borderMode=cv2.BORDER_CONSTANT)
