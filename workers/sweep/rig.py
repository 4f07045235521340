"""A calibrated camera rig: the cameras of one capture set-up, with their image file names."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from workers.camera import Camera
from workers.common.errors import InputError


class RigError(InputError):
    """A rig or its images are unusable; ``camera`` (or None for the whole rig) and ``field`` say where, ``problem``
    what is wrong (an :class:`~workers.common.errors.InputError`: 422 ``invalid_rig`` in the service)."""

    code = "invalid_rig"

    def __init__(self, camera: str | None, field_name: str, problem: str) -> None:
        self.camera = camera
        self.field = field_name
        self.problem = problem
        where = f"camera {camera!r}" if camera is not None else "rig"
        super().__init__(f"{where}: field {field_name!r}: {problem}")


@dataclass(frozen=True, eq=False)
class Rig:
    """Cameras (at least 2, unique names) plus optional image file names and a depth range.

    image_files: one file name per camera, relative to an images folder (default: the names).
    depth_range: (near, far) metres along a virtual camera's axis, when the capture set-up knows it.
    """

    cameras: tuple[Camera, ...]
    image_files: tuple[str, ...] = field(default=())
    depth_range: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        cams = tuple(self.cameras)
        object.__setattr__(self, "cameras", cams)
        if len(cams) < 2:
            raise RigError(None, "cameras", f"a rig needs at least 2 cameras, got {len(cams)}")
        seen: set[str] = set()
        for c in cams:
            if not isinstance(c, Camera):
                raise RigError(None, "cameras", f"expected Camera objects, got {type(c).__name__}")
            if c.name in seen:
                raise RigError(c.name, "name", "used by two cameras")
            seen.add(c.name)
        files = tuple(self.image_files) or tuple(c.name for c in cams)
        if len(files) != len(cams):
            raise RigError(None, "image_files", f"{len(files)} file names for {len(cams)} cameras")
        object.__setattr__(self, "image_files", files)
        if self.depth_range is not None:
            near, far = map(float, self.depth_range)
            if not 0 < near < far < np.inf:
                raise RigError(None, "depth_range", f"needs 0 < near < far, got {self.depth_range}")
            object.__setattr__(self, "depth_range", (near, far))

    def __len__(self) -> int:
        return len(self.cameras)

    def __getitem__(self, key: int | str) -> Camera:
        return self.cameras[self.index(key) if isinstance(key, str) else key]

    @property
    def names(self) -> list[str]:
        """Camera names in rig order."""
        return [c.name for c in self.cameras]

    def index(self, name: str) -> int:
        """Position of the camera called ``name``; RigError when there is none."""
        for i, c in enumerate(self.cameras):
            if c.name == name:
                return i
        raise RigError(name, "name", f"no such camera (have {', '.join(self.names)})")

    def centers(self) -> np.ndarray:
        """Camera centres, (N, 3) float64 world."""
        return np.stack([c.center for c in self.cameras])

    def axes(self) -> np.ndarray:
        """Unit optical axes, (N, 3) float64 world."""
        return np.stack([c.axis for c in self.cameras])

    def focus_point(self) -> np.ndarray:
        """The point nearest (least squares) to all optical axes, (3,) float64 world: what the rig looks at.

        Falls back to 2 m in front of the mean centre when the axes are (nearly) parallel.
        """
        A = np.zeros((3, 3))
        b = np.zeros(3)
        for c, d in zip(self.centers(), self.axes()):
            proj = np.eye(3) - np.outer(d, d)
            A += proj
            b += proj @ c
        if np.linalg.cond(A) > 1e6:
            return self.centers().mean(axis=0) + 2.0 * self.axes().mean(axis=0)
        return np.linalg.solve(A, b)

    def radius(self) -> float:
        """The rig's radius, metres: the median distance of the camera centres from :meth:`focus_point`."""
        return float(np.median(np.linalg.norm(self.centers() - self.focus_point(), axis=1)))

    def auto_depth_range(self, virtual: Camera) -> tuple[float, float]:
        """(near, far) metres along ``virtual``'s axis: ``depth_range`` when the rig gives one, else the
        range of the rig's working volume, from the rig geometry alone (no silhouettes needed).

        The rule: cameras set up around a scene look at it, so the scene lies about their focus point
        ``c`` (:meth:`focus_point`, the least-squares point nearest to all optical axes) and ends about
        where the cameras stand, on the sphere of the rig radius ``R`` (:meth:`radius`) about ``c`` (a
        studio dome's wall, the far side of a room with cameras on its walls). Content nearer to a
        camera than half-way to ``c`` is seen by too few cameras to be matched. With ``z_c`` the depth
        of ``c`` in ``virtual``::

            far  = z_c + R                                   (the far side of that sphere)
            near = max(z_c - R / 2, far / NEAR_FAR_RATIO)    (half-way in; a virtual camera standing
                                                              inside the volume gets far / 20)

        A virtual camera at the rig's home orbit (``z_c = R``) so sweeps R/2 .. 2R. RigError when the
        whole volume is behind ``virtual`` (``far <= 0``): give near/far.
        """
        if self.depth_range is not None:
            return self.depth_range
        z = float(virtual.to_camera(self.focus_point()[None])[0, 2])
        radius = self.radius()
        if not radius > 0:
            raise RigError(None, "cameras", "every camera stands at the focus point (no working volume); give near/far")
        far = z + radius
        if not far > 0:
            raise RigError(virtual.name, "pose", "the rig's working volume is behind the virtual camera; give near/far")
        return max(z - 0.5 * radius, far / NEAR_FAR_RATIO), far

    def require_baseline(self) -> None:
        """RigError when every camera stands at the same place: a plane sweep finds depth only between cameras at
        two places at least (a rig of one spot gives a collapsed depth range and flat views)."""
        centres = self.centers()
        spread = float(np.max(np.linalg.norm(centres - centres[0], axis=1)))
        if not spread > 1e-9 * max(1.0, float(np.max(np.abs(centres)))):
            raise RigError(None, "cameras", "every camera stands at the same place: views between cameras need "
                                            "cameras at two places at least (a baseline)")

    def rescaled(self, metres_per_unit: float) -> "Rig":
        """The same rig with world lengths given in another unit: every translation (so every camera
        centre) and ``depth_range`` multiplied by ``metres_per_unit`` (e.g. 0.01 for a file in
        centimetres); intrinsics, rotations and image names unchanged."""
        f = float(metres_per_unit)
        if not (np.isfinite(f) and f > 0):
            raise RigError(None, "units", f"the scale must be a positive number of metres per unit, "
                                          f"got {metres_per_unit!r}")
        if f == 1.0:
            return self
        cams = tuple(Camera(c.name, c.K, c.R, c.t * f, c.width, c.height, c.dist) for c in self.cameras)
        dr = None if self.depth_range is None else (self.depth_range[0] * f, self.depth_range[1] * f)
        return Rig(cams, self.image_files, dr)


NEAR_FAR_RATIO = 20.0
"""Largest far/near of :meth:`Rig.auto_depth_range` (planes are uniform in inverse depth: a nearer near
thins the planes at the subject)."""


def depth_range_from_box(camera: Camera, lo: np.ndarray, hi: np.ndarray, margin: float = 0.05) -> tuple[float, float]:
    """(near, far) depths along ``camera``'s axis covering the axis-aligned box [lo, hi] (3,) each,
    widened by ``margin`` (fraction); near is clamped to a small positive value."""
    lo = np.asarray(lo, np.float64)
    hi = np.asarray(hi, np.float64)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    z = camera.to_camera(corners)[:, 2]
    far = float(z.max()) * (1 + margin)
    near = max(float(z.min()) * (1 - margin), 1e-3 * far)
    if not far > 0:
        raise RigError(camera.name, "pose", "the box is behind the camera")
    return near, far
