"""A calibrated camera rig: the cameras of one capture set-up, with their image file names."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from workers.camera import Camera


class RigError(ValueError):
    """A rig or its images are unusable; ``camera`` (or None for the whole rig) and ``field`` say where."""

    def __init__(self, camera: str | None, field_name: str, problem: str) -> None:
        self.camera = camera
        self.field = field_name
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
        """The point nearest (least squares) to all optical axes, (3,): what the rig looks at.

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

    def auto_depth_range(self, virtual: Camera) -> tuple[float, float]:
        """(near, far) for ``virtual``: ``depth_range`` when known, else 0.5x..2x the depth of
        :meth:`focus_point` (a heuristic for object-centred rigs; pass near/far when you know better)."""
        if self.depth_range is not None:
            return self.depth_range
        z = float(virtual.to_camera(self.focus_point()[None])[0, 2])
        if not z > 0:
            raise RigError(virtual.name, "pose", "the rig's focus point is behind the virtual camera; give near/far")
        return 0.5 * z, 2.0 * z


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
