"""The frames of a job as any node reads them: stills straight from the uploaded zip or folder (only the photos
a task needs), a video's frames from the job's work area (decoded once, by the job, at the working resolution).

A frame comes *raw* (as the lens saw it; stills at their native size) with its ``pixel_scale``: its width over the
working width. The dense pass wants it at the working resolution and undistorted (:func:`working_image`); the
orthophoto samples the raw image through the lens at its own resolution (the photos' own ground resolution).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from workers.common import images
from workers.workarea import InputRef, WorkArea

from ..calibration import Intrinsics
from ..frames import read_stills


@dataclass(frozen=True)
class PhotoSource:
    """Where frames come from: the stills of ``media`` (``stored`` False) or, for a video, PNGs the job stored in
    ``work`` under ``frames/<name>.png`` (``stored`` True); the working size and the raw frames' size (w, h)."""

    media: InputRef
    working_size: tuple[int, int]
    raw_size: tuple[int, int]
    stored: bool = False
    work: WorkArea | None = None

    @property
    def raw_scale(self) -> float:
        """A raw frame's pixels per working pixel (a still's native size over the working size; 1 for a video's
        stored frames)."""
        return self.raw_size[0] / self.working_size[0]

    def raw(self, names: list[str]) -> dict[str, tuple[np.ndarray, float]]:
        """``name -> (image (H, W, 3) uint8 BGR as the lens saw it, its width / the working width)`` for the
        frames of ``names`` that can be read (undecodable ones are left out: the tracking stage reported them)."""
        out = {}
        if self.stored:
            for n in names:
                img = cv2.imdecode(np.frombuffer(self.work.get(stored_frame(n)), np.uint8), cv2.IMREAD_COLOR)
                out[n] = (img, img.shape[1] / self.working_size[0])
            return out
        limit = images.max_pixels_from_env()
        for n, data in read_stills(self.media.local_path(), names, self.media.name).items():
            try:
                img = images.decode_image(data, cv2.IMREAD_COLOR, limit)
            except (OSError, images.ImageInputError):
                continue
            out[n] = (img, img.shape[1] / self.working_size[0])
        return out

    def working(self, names: list[str], intr: Intrinsics) -> dict[str, np.ndarray]:
        """``name -> (h, w, 3) uint8 BGR`` at the working resolution, undistorted with ``intr`` (working-resolution
        intrinsics; their distortion, if any)."""
        return {n: working_image(img, self.working_size, intr) for n, (img, _) in self.raw(names).items()}


def stored_frame(name: str) -> str:
    """The work-area name of a stored video frame."""
    return f"frames/{name}.png"


@functools.lru_cache(maxsize=4)
def _undistort_maps(key: tuple) -> tuple[np.ndarray, np.ndarray]:
    K = np.array(key[0]).reshape(3, 3)
    dist = np.array(key[1])
    size = key[2]
    return cv2.initUndistortRectifyMap(K, dist, None, K, size, cv2.CV_16SC2)


def working_image(raw: np.ndarray, working_size: tuple[int, int], intr: Intrinsics) -> np.ndarray:
    """A raw frame (H, W, 3) uint8 -> the working resolution ``working_size`` (w, h) (INTER_AREA), undistorted with
    ``intr`` (working-resolution intrinsics; none when ``intr.dist`` is None), as frame selection makes it."""
    img = raw if raw.shape[1::-1] == tuple(working_size) else cv2.resize(raw, working_size, interpolation=cv2.INTER_AREA)
    if intr.dist is None or not np.any(intr.dist):
        return img
    m1, m2 = _undistort_maps((tuple(intr.K.ravel()), tuple(np.asarray(intr.dist).ravel()), tuple(working_size)))
    return cv2.remap(img, m1, m2, cv2.INTER_LINEAR)
