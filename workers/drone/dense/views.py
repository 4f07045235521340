"""A posed image: a pinhole :class:`~workers.camera.Camera` and the image it took."""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from workers.camera import Camera


@dataclass(frozen=True)
class View:
    """``image`` (h, w, 3) uint8 BGR taken by ``camera``: its width and height the image's, and no distortion
    (the dense sweep resamples images through the pinhole model alone; the orthophoto takes a lens's
    distortion separately)."""

    camera: Camera
    image: np.ndarray

    def __post_init__(self) -> None:
        h, w = self.image.shape[:2]
        if self.camera.size != (w, h):
            raise ValueError(f"view {self.camera.name!r}: camera is {self.camera.size}, image {(w, h)}")
        if self.camera.has_distortion:
            raise ValueError(f"view {self.camera.name!r}: the dense engine needs undistorted images")

    @classmethod
    def from_pose(cls, name: str, image: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray) -> "View":
        """The view of ``image`` (h, w, 3) uint8 BGR by the camera ``K`` (3, 3), world-to-camera ``R`` (3, 3)
        and ``t`` (3,) (model units)."""
        return cls(Camera(name, K, R, t, image.shape[1], image.shape[0]), image)

    def gray(self) -> np.ndarray:
        """(h, w) float32 grey levels 0..255."""
        return cv2.cvtColor(self.image, cv2.COLOR_BGR2GRAY).astype(np.float32)

    def scaled(self, factor: float) -> "View":
        """The view with its image resized by ``factor`` (INTER_AREA) and K to match: each axis scaled by the
        ratio of the rounded sizes, pixel centres kept."""
        if factor == 1.0:
            return self
        cam = self.camera
        w, h = cam.size
        size = (max(1, int(round(w * factor))), max(1, int(round(h * factor))))
        sx, sy = size[0] / w, size[1] / h
        S = np.array([[sx, 0, 0.5 * sx - 0.5], [0, sy, 0.5 * sy - 0.5], [0, 0, 1]])
        image = cv2.resize(self.image, size, interpolation=cv2.INTER_AREA)
        return View(Camera(cam.name, S @ cam.K, cam.R, cam.t, size[0], size[1]), image)
