"""The pinhole camera shared by every engine.

Conventions (DESIGN.md): intrinsics ``K`` (3x3), world-to-camera rotation ``R`` (3x3) and
translation ``t`` (3,), so that ``x_cam = R @ X + t``; OpenCV axes (x right, y down, z forward);
pixel (0, 0) is the centre of the top-left pixel. Depth means ``z`` in the camera frame (distance
along the optical axis), not the length of the ray. Optional ``dist`` holds OpenCV distortion
coefficients ``(k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tx, ty]]]])``.

API:
- ``Camera(name, K, R, t, width, height, dist=None)``: validated on construction; a bad field raises
  :class:`CameraError` (an :class:`~workers.common.errors.InputError`, so a ``ValueError``: 422
  ``invalid_camera`` in the service) naming the camera and the field.
- ``cam.center`` (3,), ``cam.axis`` (3,) optical axis in world, ``cam.P`` (3, 4).
- ``cam.project(X) -> (uv, z)``, ``cam.backproject(uv, depth) -> X``, ``cam.rays(uv) -> unit dirs``,
  ``cam.pixel_grid()``.
- ``Camera.look_at(name, eye, target, up, fov_deg, width, height)``, ``Camera.from_center(...)``.
- ``interpolate(a, b, s)``: slerp of rotation, lerp of centre and intrinsics.
- ``distort_normalised(xn, yn, K, dist) -> (u, v)``: OpenCV's lens model on normalised points (what ``project``
  and the drone orthophoto use).
- ``cam.scaled(f)``: the same camera for an image resized by ``f``.
- ``cam.to_dict()`` / ``Camera.from_dict(d)`` (JSON-able).
- quaternion helpers ``quat_to_rotation`` / ``rotation_to_quat`` (w, x, y, z; Hamilton).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from workers.common.errors import InputError

_ORTHO_TOL = 1e-5
_DIST_LENGTHS = (4, 5, 8, 12, 14)


class CameraError(InputError):
    """A camera's calibration is unusable; ``camera`` and ``field`` say which and where, ``problem`` what is wrong."""

    code = "invalid_camera"

    def __init__(self, camera: str, field_name: str, problem: str) -> None:
        self.camera = camera
        self.field = field_name
        self.problem = problem
        super().__init__(f"camera {camera!r}: field {field_name!r}: {problem}")


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated pinhole camera (see the module docstring for conventions).

    Arrays are stored as float64 copies: ``K`` (3, 3), ``R`` (3, 3), ``t`` (3,), ``dist`` (n,) or None.
    ``width``/``height`` are the image size in pixels.
    """

    name: str
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int
    dist: np.ndarray | None = field(default=None)

    def __post_init__(self) -> None:
        name = str(self.name)
        object.__setattr__(self, "name", name)
        object.__setattr__(self, "K", _validated_K(name, self.K))
        object.__setattr__(self, "R", _validated_R(name, self.R))
        object.__setattr__(self, "t", _validated_vec3(name, "t", self.t))
        object.__setattr__(self, "width", _validated_size(name, "width", self.width))
        object.__setattr__(self, "height", _validated_size(name, "height", self.height))
        object.__setattr__(self, "dist", _validated_dist(name, self.dist))

    # --- geometry -------------------------------------------------------------------------
    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, (3,) float64: ``-R^T t``."""
        return -self.R.T @ self.t

    @property
    def axis(self) -> np.ndarray:
        """Unit optical axis (camera +z) in world coordinates, (3,) float64."""
        return self.R[2].copy()

    @property
    def P(self) -> np.ndarray:
        """Projection matrix ``K [R | t]``, (3, 4) float64 (ignores distortion)."""
        return self.K @ np.hstack([self.R, self.t[:, None]])

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.width, self.height

    @property
    def has_distortion(self) -> bool:
        """True when ``dist`` holds any non-zero coefficient."""
        return self.dist is not None and bool(np.any(self.dist != 0))

    def to_camera(self, X: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> camera-frame points (N, 3), float64."""
        return np.asarray(X, np.float64).reshape(-1, 3) @ self.R.T + self.t

    def project(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points.

        X: (N, 3) world coordinates. Returns ``uv`` (N, 2) float64 pixels (distortion applied when
        set) and ``z`` (N,) float64 depth along the optical axis; points with ``z <= 0`` get
        ``uv = nan``.
        """
        Xc = self.to_camera(X)
        z = Xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = Xc[:, :2] / z[:, None]
        xn[z <= 0] = np.nan
        if self.has_distortion:
            ok = np.isfinite(xn).all(axis=1)
            uv = np.full_like(xn, np.nan)
            if ok.any():
                u, v = distort_normalised(xn[ok, 0], xn[ok, 1], self.K, self.dist)
                uv[ok, 0], uv[ok, 1] = u, v
            return uv, z
        uv = xn * np.array([self.K[0, 0], self.K[1, 1]]) + np.array([self.K[0, 2], self.K[1, 2]])
        uv[:, 0] += self.K[0, 1] * xn[:, 1]
        return uv, z

    def normalized(self, uv: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) -> normalised image coordinates (N, 2) with distortion removed."""
        uv = np.asarray(uv, np.float64).reshape(-1, 2)
        if self.has_distortion:
            return cv2.undistortPoints(uv[:, None, :], self.K, self.dist).reshape(-1, 2)
        h = np.hstack([uv, np.ones((len(uv), 1))])
        return (h @ np.linalg.inv(self.K).T)[:, :2]

    def backproject(self, uv: np.ndarray, depth: np.ndarray | float) -> np.ndarray:
        """Pixels (N, 2) at depth (N,) or scalar (z along the optical axis, metres) -> world (N, 3)."""
        xn = self.normalized(uv)
        d = np.broadcast_to(np.asarray(depth, np.float64), (len(xn),))
        Xc = np.hstack([xn, np.ones((len(xn), 1))]) * d[:, None]
        return (Xc - self.t) @ self.R

    def rays(self, uv: np.ndarray) -> np.ndarray:
        """Unit viewing directions in world coordinates (N, 3) for pixels (N, 2)."""
        xn = self.normalized(uv)
        d = np.hstack([xn, np.ones((len(xn), 1))]) @ self.R
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def pixel_grid(self) -> np.ndarray:
        """All pixel centres, (height, width, 2) float64 ``(u, v)``."""
        u, v = np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))
        return np.stack([u, v], axis=-1)

    # --- derived cameras ------------------------------------------------------------------
    def scaled(self, factor: float, name: str | None = None) -> "Camera":
        """The camera of the image resized by ``factor`` (pixel-centre convention kept)."""
        S = np.diag([factor, factor, 1.0])
        K = S @ self.K
        K[0, 2] = (self.K[0, 2] + 0.5) * factor - 0.5
        K[1, 2] = (self.K[1, 2] + 0.5) * factor - 0.5
        w = max(1, int(round(self.width * factor)))
        h = max(1, int(round(self.height * factor)))
        return replace(self, name=name or self.name, K=K, width=w, height=h)

    def renamed(self, name: str) -> "Camera":
        """The same camera under another name."""
        return replace(self, name=name)

    @classmethod
    def from_center(
        cls, name: str, K: np.ndarray, R: np.ndarray, center: np.ndarray, width: int, height: int,
        dist: np.ndarray | None = None,
    ) -> "Camera":
        """A camera from its rotation (world-to-camera) and centre (world), (3,)."""
        R = np.asarray(R, np.float64)
        return cls(name, K, R, -R @ np.asarray(center, np.float64), width, height, dist)

    @classmethod
    def look_at(
        cls, name: str, eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0),
        fov_deg: float = 60.0, width: int = 640, height: int = 480,
    ) -> "Camera":
        """A camera at ``eye`` looking at ``target`` with world ``up`` shown upwards in the image.

        ``fov_deg`` is the horizontal field of view; square pixels, principal point at the centre.
        """
        eye = np.asarray(eye, np.float64)
        z = np.asarray(target, np.float64) - eye
        if not np.linalg.norm(z) > 0:
            raise CameraError(name, "target", "equals the eye position")
        z /= np.linalg.norm(z)
        x = np.cross(z, np.asarray(up, np.float64))
        if np.linalg.norm(x) < 1e-9:
            raise CameraError(name, "up", "is parallel to the viewing direction")
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        if not 0 < fov_deg < 180:
            raise CameraError(name, "fov_deg", f"must be in (0, 180), got {fov_deg}")
        f = 0.5 * width / np.tan(np.radians(fov_deg) / 2)
        K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
        return cls.from_center(name, K, np.stack([x, y, z]), eye, width, height)

    # --- serialisation --------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict (the format of our rig JSON files)."""
        d: dict[str, Any] = {
            "name": self.name, "width": self.width, "height": self.height,
            "K": self.K.tolist(), "R": self.R.tolist(), "t": self.t.tolist(),
        }
        if self.dist is not None:
            d["dist"] = self.dist.tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any], name: str | None = None) -> "Camera":
        """Inverse of :meth:`to_dict`; ``center`` may replace ``t``. Missing fields raise CameraError."""
        cam_name = str(d.get("name", name if name is not None else "?"))
        for key in ("K", "R", "width", "height"):
            if key not in d:
                raise CameraError(cam_name, key, "missing")
        if "t" in d:
            t = d["t"]
        elif "center" in d:
            t = -_validated_R(cam_name, d["R"]) @ _validated_vec3(cam_name, "center", d["center"])
        else:
            raise CameraError(cam_name, "t", "missing (give 't' or 'center')")
        return cls(cam_name, d["K"], d["R"], t, d["width"], d["height"], d.get("dist"))


def interpolate(a: Camera, b: Camera, s: float, name: str | None = None) -> Camera:
    """The camera a fraction ``s`` of the way from ``a`` (s=0) to ``b`` (s=1).

    Rotation by quaternion slerp, centre and intrinsics by linear interpolation; the image size is
    ``a``'s (``b``'s intrinsics are rescaled to it first when sizes differ); no distortion.
    """
    Kb = b.K.copy()
    if (a.width, a.height) != (b.width, b.height):
        Kb = b.scaled(a.width / b.width).K
    q = slerp(rotation_to_quat(a.R), rotation_to_quat(b.R), s)
    K = (1 - s) * a.K + s * Kb
    C = (1 - s) * a.center + s * b.center
    return Camera.from_center(name or f"{a.name}~{b.name}@{s:.3f}", K, quat_to_rotation(q), C, a.width, a.height)


def quat_to_rotation(q: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) -> rotation matrix (3, 3) float64."""
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def rotation_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) -> unit quaternion (w, x, y, z) with w >= 0, float64."""
    R = np.asarray(R, np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = 2 * np.sqrt(tr + 1)
        q = [s / 4, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2 * np.sqrt(1 + R[i, i] - R[j, j] - R[k, k])
        q = np.zeros(4)
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = s / 4
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    q = np.asarray(q) / np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def slerp(q0: np.ndarray, q1: np.ndarray, s: float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (4,), shortest path."""
    q0 = np.asarray(q0, np.float64)
    q1 = np.asarray(q1, np.float64)
    d = float(np.dot(q0, q1))
    if d < 0:
        q1, d = -q1, -d
    if d > 0.9995:  # nearly equal: lerp avoids dividing by sin(~0)
        q = q0 + s * (q1 - q0)
        return q / np.linalg.norm(q)
    th = np.arccos(d)
    return (np.sin((1 - s) * th) * q0 + np.sin(s * th) * q1) / np.sin(th)


def _as_array(name: str, field_name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise CameraError(name, field_name, "is not numeric") from None
    if arr.size == int(np.prod(shape)) and arr.shape != shape:
        arr = arr.reshape(shape)
    if arr.shape != shape:
        raise CameraError(name, field_name, f"must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise CameraError(name, field_name, "contains NaN or infinity")
    return arr


def _validated_K(name: str, K: Any) -> np.ndarray:
    K = _as_array(name, "K", K, (3, 3))
    if not np.allclose(K[2], [0, 0, 1], atol=1e-9):
        raise CameraError(name, "K", f"last row must be [0, 0, 1], got {K[2].tolist()}")
    if K[1, 0] != 0:
        raise CameraError(name, "K", "must be upper triangular")
    if abs(np.linalg.det(K)) < 1e-12 or K[0, 0] == 0 or K[1, 1] == 0:
        raise CameraError(name, "K", "is singular (a focal length is zero)")
    if K[0, 0] < 0 or K[1, 1] < 0:
        raise CameraError(name, "K", "focal lengths must be positive")
    return K


def _validated_R(name: str, R: Any) -> np.ndarray:
    R = _as_array(name, "R", R, (3, 3))
    err = float(np.abs(R @ R.T - np.eye(3)).max())
    if err > _ORTHO_TOL:
        raise CameraError(name, "R", f"is not orthonormal (max |R R^T - I| = {err:.3g})")
    if np.linalg.det(R) < 0:
        raise CameraError(name, "R", "is a reflection (det = -1), not a rotation")
    return R


def _validated_vec3(name: str, field_name: str, v: Any) -> np.ndarray:
    return _as_array(name, field_name, v, (3,))


def _validated_size(name: str, field_name: str, v: Any) -> int:
    try:
        n = int(v)
    except (TypeError, ValueError):
        raise CameraError(name, field_name, f"must be an integer, got {v!r}") from None
    if n != v or n <= 0:
        raise CameraError(name, field_name, f"must be a positive integer, got {v!r}")
    return n


def _validated_dist(name: str, dist: Any) -> np.ndarray | None:
    if dist is None:
        return None
    try:
        d = np.array(dist, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise CameraError(name, "dist", "is not numeric") from None
    if d.size not in _DIST_LENGTHS:
        raise CameraError(name, "dist", f"needs {', '.join(map(str, _DIST_LENGTHS))} coefficients, got {d.size}")
    if not np.all(np.isfinite(d)):
        raise CameraError(name, "dist", "contains NaN or infinity")
    return d


def distort_normalised(xn: np.ndarray, yn: np.ndarray, K: np.ndarray, dist: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Normalised undistorted image points xn, yn (N,) float64 -> the pixels (u, v) (N,) float64 where a lens
    with OpenCV distortion ``dist`` (k1 k2 p1 p2 [k3], or longer) and pinhole ``K`` (3, 3) shows them, as
    :func:`cv2.projectPoints` computes them (its fx, fy, cx, cy; no skew): OpenCV's model written out for up to five
    coefficients (~10x faster on a frame's worth of points), projectPoints itself for the rational, thin-prism and
    tilted models."""
    d = np.asarray(dist, np.float64).ravel()
    if len(d) > 5:
        pts = np.column_stack([xn, yn, np.ones_like(xn)])
        raw = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), np.asarray(K, np.float64), d)[0].reshape(-1, 2)
        return raw[:, 0], raw[:, 1]
    k1, k2, p1, p2, k3 = np.pad(d, (0, 5 - len(d)))
    xy = xn * yn
    r2 = xn * xn + yn * yn
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = xn * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * xn * xn)
    yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xy
    return K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]
