"""What every dense and map task of one job shares (:class:`MapJob`), and the small description of a posed frame a
task is sent (:class:`Pose`): the bulk (images, depth maps, tiles) goes through the job's work area."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.camera import Camera
from workers.workarea import WorkArea

from ..calibration import Intrinsics
from ..dense.views import View
from ..params import ReconstructionParams
from .photos import PhotoSource


@dataclass(frozen=True)
class Pose:
    """A registered frame: its index in the model, file name, world-to-camera ``R`` (3, 3) and ``t`` (3,)."""

    frame: int
    name: str
    R: np.ndarray
    t: np.ndarray


@dataclass(frozen=True)
class MapJob:
    """The work area, where the frames come from, the parameters, and the model's camera at the working
    resolution: ``intrinsics`` (its distortion: the lens the frames are undistorted with for the dense pass and
    sampled through for the orthophoto; its K the undistorted image's pinhole)."""

    work: WorkArea
    photos: PhotoSource
    params: ReconstructionParams
    intrinsics: Intrinsics

    @property
    def K(self) -> np.ndarray:
        return self.intrinsics.K

    def dense_views(self, poses: list[Pose]) -> dict[int, View]:
        """Frame -> its :class:`View` for the dense pass: undistorted at the working resolution, scaled by
        ``dense_scale``, for the poses whose frames can be read."""
        images = self.photos.working([p.name for p in poses], self.intrinsics)
        return {p.frame: View.from_pose(p.name, images[p.name], self.K, p.R, p.t).scaled(self.params.dense_scale)
                for p in poses if p.name in images}

    def dense_camera(self, pose: Pose) -> Camera:
        """A frame's camera at the dense resolution (for its depth range and footprint; the sweep itself uses
        :meth:`dense_views`)."""
        w, h = self.photos.working_size
        return Camera(pose.name, self.K, pose.R, pose.t, w, h).scaled(self.params.dense_scale)

    def raw_camera(self, pose: Pose) -> Camera:
        """A frame's camera for its raw image (the lens's distortion left out: the orthophoto samples through it)."""
        scale = self.photos.raw_scale
        K = self.intrinsics.scaled(scale).K
        w, h = self.photos.raw_size
        return Camera(pose.name, K, pose.R, pose.t, w, h)
