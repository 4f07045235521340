"""Camera models that plug into the bundle adjuster (:mod:`workers.drone.bundle`).

A model turns per-camera parameter rows and 3D points into reprojection residuals and their
analytic Jacobians. Every model stores the rotation as a Rodrigues vector in the first three
parameters and the translation in the next three (``x = R X + t``); the optimiser's rotation
increment is a left-multiplied rotation vector ``R <- exp([d]x) R``, so a Jacobian's rotation
columns are ``d residual / d d`` at ``d = 0`` and :meth:`retract` composes instead of adding.

- :class:`PinholeModel`: our pipeline's camera, known ``K`` per camera, OpenCV axes; 6 free
  parameters (rotation, translation). Residual ``K (R X + t) / z - observed`` in pixels.
- :class:`BALModel`: the "Bundle Adjustment in the Large" camera, 9 parameters (rotation,
  translation, f, k1, k2), ``p = -P_xy / P_z`` and ``f (1 + k1 |p|^2 + k2 |p|^4) p``.
- :class:`RadialModel`: self-calibration, 6 pose parameters per camera and intrinsics ``f, k1, k2``
  *shared* by every camera (COLMAP's RADIAL camera with a fixed principal point): ``x = P_xy / P_z``,
  pixel ``f (1 + k1 |x|^2 + k2 |x|^4) x + c``. Models with shared parameters set ``n_shared`` and
  implement :meth:`CameraModel.evaluate_shared`; the solver adds the shared block to its reduced system.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

_MIN_DEPTH = 1e-9


@njit(cache=True)
def _rotation_matrix(rx: float, ry: float, rz: float) -> np.ndarray:
    """Rodrigues vector -> rotation matrix (3, 3); Taylor form near zero."""
    th2 = rx * rx + ry * ry + rz * rz
    R = np.empty((3, 3))
    if th2 < 1e-16:
        R[0, 0] = 1.0
        R[0, 1] = -rz
        R[0, 2] = ry
        R[1, 0] = rz
        R[1, 1] = 1.0
        R[1, 2] = -rx
        R[2, 0] = -ry
        R[2, 1] = rx
        R[2, 2] = 1.0
        return R
    th = np.sqrt(th2)
    a = np.sin(th) / th
    b = (1.0 - np.cos(th)) / th2
    R[0, 0] = 1.0 - b * (ry * ry + rz * rz)
    R[0, 1] = -a * rz + b * rx * ry
    R[0, 2] = a * ry + b * rx * rz
    R[1, 0] = a * rz + b * rx * ry
    R[1, 1] = 1.0 - b * (rx * rx + rz * rz)
    R[1, 2] = -a * rx + b * ry * rz
    R[2, 0] = -a * ry + b * rx * rz
    R[2, 1] = a * rx + b * ry * rz
    R[2, 2] = 1.0 - b * (rx * rx + ry * ry)
    return R


@njit(cache=True)
def _rotation_vector(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) -> Rodrigues vector (3,), stable near 0 and pi."""
    c = min(1.0, max(-1.0, 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)))
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    th = np.arccos(c)
    if th < 1e-6:
        return 0.5 * v
    if th < np.pi - 1e-4:
        return v * (th / (2.0 * np.sin(th)))
    # Near pi: (R + R^T) / 2 = c I + (1 - c) a a^T gives the axis a; its sign comes from the skew part.
    i = 0
    if R[1, 1] > R[i, i]:
        i = 1
    if R[2, 2] > R[i, i]:
        i = 2
    axis = np.empty(3)
    for k in range(3):
        axis[k] = 0.5 * (R[i, k] + R[k, i])
    axis[i] = np.sqrt(max(0.0, (R[i, i] - c) / (1.0 - c)))
    for k in range(3):
        if k != i:
            axis[k] = (R[i, k] + R[k, i]) / (2.0 * (1.0 - c) * axis[i])
    axis /= np.sqrt(axis[0] ** 2 + axis[1] ** 2 + axis[2] ** 2)
    if axis[0] * v[0] + axis[1] * v[1] + axis[2] * v[2] < 0:
        axis = -axis
    return axis * th


@njit(cache=True)
def _rotation_matrices(params: np.ndarray) -> np.ndarray:
    n = params.shape[0]
    out = np.empty((n, 3, 3))
    for i in range(n):
        out[i] = _rotation_matrix(params[i, 0], params[i, 1], params[i, 2])
    return out


@njit(cache=True)
def _retract(params: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """params (n, p), delta (n, p) -> params with R <- exp(d) R and the rest added."""
    out = params + delta
    for i in range(params.shape[0]):
        if delta[i, 0] == 0.0 and delta[i, 1] == 0.0 and delta[i, 2] == 0.0:
            out[i, :3] = params[i, :3]
            continue
        R = _rotation_matrix(params[i, 0], params[i, 1], params[i, 2])
        D = _rotation_matrix(delta[i, 0], delta[i, 1], delta[i, 2])
        out[i, :3] = _rotation_vector(D @ R)
    return out


@njit(cache=True, inline="always")
def _camera_point(R, X, p, params, c):  # pragma: no cover - compiled
    """Point p of X (P, 3) in camera c's frame: q = R X[p] and P = q + t (t = params[c, 3:6]), as six floats."""
    x0, x1, x2 = X[p, 0], X[p, 1], X[p, 2]
    q0 = R[0, 0] * x0 + R[0, 1] * x1 + R[0, 2] * x2
    q1 = R[1, 0] * x0 + R[1, 1] * x1 + R[1, 2] * x2
    q2 = R[2, 0] * x0 + R[2, 1] * x1 + R[2, 2] * x2
    return q0, q1, q2, q0 + params[c, 3], q1 + params[c, 4], q2 + params[c, 5]


@njit(cache=True, inline="always")
def _pose_rows(Jc, Jp, o, R, q0, q1, q2, a0, a1, a2, b0, b1, b2):  # pragma: no cover - compiled
    """Observation o's pose columns Jc[o, :, :6] (rotation increment, translation) and point rows Jp[o] from
    d(residual)/dP, the rows (a0, a1, a2) and (b0, b1, b2), with q = R X: dP/d(rotation increment) = -[q]x,
    dP/dt = I, dP/dX = R."""
    Jc[o, 0, 0] = -a1 * q2 + a2 * q1
    Jc[o, 0, 1] = a0 * q2 - a2 * q0
    Jc[o, 0, 2] = -a0 * q1 + a1 * q0
    Jc[o, 1, 0] = -b1 * q2 + b2 * q1
    Jc[o, 1, 1] = b0 * q2 - b2 * q0
    Jc[o, 1, 2] = -b0 * q1 + b1 * q0
    Jc[o, 0, 3] = a0
    Jc[o, 0, 4] = a1
    Jc[o, 0, 5] = a2
    Jc[o, 1, 3] = b0
    Jc[o, 1, 4] = b1
    Jc[o, 1, 5] = b2
    for k in range(3):
        Jp[o, 0, k] = a0 * R[0, k] + a1 * R[1, k] + a2 * R[2, k]
        Jp[o, 1, k] = b0 * R[0, k] + b1 * R[1, k] + b2 * R[2, k]


@njit(cache=True, inline="always")
def _radial_rows(J, o, first, f, d, r2, px, py):  # pragma: no cover - compiled
    """Observation o's derivatives by the focal length f and the radial terms k1, k2 into J[o, :, first:first + 3],
    for the pixel f d (px, py) with d = 1 + k1 r2 + k2 r2^2."""
    J[o, 0, first] = d * px
    J[o, 1, first] = d * py
    J[o, 0, first + 1] = f * r2 * px
    J[o, 1, first + 1] = f * r2 * py
    J[o, 0, first + 2] = f * r2 * r2 * px
    J[o, 1, first + 2] = f * r2 * r2 * py


@njit(parallel=True, cache=True, fastmath=True)
def _pinhole_kernel(params, intr, X, ci, pj, obs, want_jac, r, Jc, Jp):
    """Residuals (N, 2) and, when ``want_jac``, Jacobians Jc (N, 2, 6), Jp (N, 2, 3)."""
    Rs = _rotation_matrices(params)
    for o in prange(ci.shape[0]):
        c = ci[o]
        p = pj[o]
        R = Rs[c]
        q0, q1, q2, P0, P1, P2 = _camera_point(R, X, p, params, c)
        P2 = max(P2, _MIN_DEPTH)
        iz = 1.0 / P2
        u = P0 * iz
        v = P1 * iz
        fx, fy = intr[c, 0], intr[c, 1]
        r[o, 0] = fx * u + intr[c, 2] - obs[o, 0]
        r[o, 1] = fy * v + intr[c, 3] - obs[o, 1]
        if not want_jac:
            continue
        # d(pixel)/dP for the two rows; the third column is the depth derivative.
        a0, a2 = fx * iz, -fx * u * iz
        b1, b2 = fy * iz, -fy * v * iz
        # dP/d(rotation increment) = -[q]x = [[0, q2, -q1], [-q2, 0, q0], [q1, -q0, 0]]
        Jc[o, 0, 0] = a2 * q1
        Jc[o, 0, 1] = a0 * q2 - a2 * q0
        Jc[o, 0, 2] = -a0 * q1
        Jc[o, 1, 0] = -b1 * q2 + b2 * q1
        Jc[o, 1, 1] = -b2 * q0
        Jc[o, 1, 2] = b1 * q0
        Jc[o, 0, 3] = a0
        Jc[o, 0, 4] = 0.0
        Jc[o, 0, 5] = a2
        Jc[o, 1, 3] = 0.0
        Jc[o, 1, 4] = b1
        Jc[o, 1, 5] = b2
        for k in range(3):
            Jp[o, 0, k] = a0 * R[0, k] + a2 * R[2, k]
            Jp[o, 1, k] = b1 * R[1, k] + b2 * R[2, k]


@njit(parallel=True, cache=True, fastmath=True)
def _bal_kernel(params, X, ci, pj, obs, want_jac, r, Jc, Jp):
    """BAL residuals (N, 2) and Jacobians Jc (N, 2, 9), Jp (N, 2, 3)."""
    Rs = _rotation_matrices(params)
    for o in prange(ci.shape[0]):
        c = ci[o]
        p = pj[o]
        R = Rs[c]
        q0, q1, q2, P0, P1, P2 = _camera_point(R, X, p, params, c)
        if abs(P2) < _MIN_DEPTH:
            P2 = -_MIN_DEPTH
        iz = 1.0 / P2
        px = -P0 * iz
        py = -P1 * iz
        f, k1, k2 = params[c, 6], params[c, 7], params[c, 8]
        r2 = px * px + py * py
        d = 1.0 + r2 * (k1 + k2 * r2)
        r[o, 0] = f * d * px - obs[o, 0]
        r[o, 1] = f * d * py - obs[o, 1]
        if not want_jac:
            continue
        # du/dp = f (d I + 2 (k1 + 2 k2 r2) p p^T)
        g = 2.0 * f * (k1 + 2.0 * k2 * r2)
        m00 = f * d + g * px * px
        m01 = g * px * py
        m11 = f * d + g * py * py
        # dp/dP = [[-iz, 0, -px iz], [0, -iz, -py iz]]
        a0 = -m00 * iz
        a1 = -m01 * iz
        a2 = -(m00 * px + m01 * py) * iz
        b0 = -m01 * iz
        b1 = -m11 * iz
        b2 = -(m01 * px + m11 * py) * iz
        _pose_rows(Jc, Jp, o, R, q0, q1, q2, a0, a1, a2, b0, b1, b2)
        _radial_rows(Jc, o, 6, f, d, r2, px, py)


@njit(parallel=True, cache=True, fastmath=True)
def _radial_kernel(params, shared, centre, X, ci, pj, obs, want_jac, r, Jc, Jp, Jg):
    """Shared-intrinsics radial camera: residuals (N, 2); with ``want_jac`` Jc (N, 2, 6), Jp (N, 2, 3)
    and Jg (N, 2, g) (derivatives by f, k1, k2 and, when ``shared`` (g,) has five, the principal point cx, cy
    that then replaces ``centre``)."""
    Rs = _rotation_matrices(params)
    f, k1, k2 = shared[0], shared[1], shared[2]
    own_centre = shared.shape[0] == 5
    cx = shared[3] if own_centre else centre[0]
    cy = shared[4] if own_centre else centre[1]
    for o in prange(ci.shape[0]):
        c = ci[o]
        p = pj[o]
        R = Rs[c]
        q0, q1, q2, P0, P1, P2 = _camera_point(R, X, p, params, c)
        P2 = max(P2, _MIN_DEPTH)
        iz = 1.0 / P2
        px = P0 * iz
        py = P1 * iz
        r2 = px * px + py * py
        d = 1.0 + r2 * (k1 + k2 * r2)
        r[o, 0] = f * d * px + cx - obs[o, 0]
        r[o, 1] = f * d * py + cy - obs[o, 1]
        if not want_jac:
            continue
        if own_centre:
            Jg[o, 0, 3] = 1.0
            Jg[o, 0, 4] = 0.0
            Jg[o, 1, 3] = 0.0
            Jg[o, 1, 4] = 1.0
        # d(pixel)/d(x, y) = f (d I + 2 (k1 + 2 k2 r2) x x^T); d(x, y)/dP = [[iz, 0, -x iz], [0, iz, -y iz]]
        g = 2.0 * f * (k1 + 2.0 * k2 * r2)
        m00 = f * d + g * px * px
        m01 = g * px * py
        m11 = f * d + g * py * py
        a0 = m00 * iz
        a1 = m01 * iz
        a2 = -(m00 * px + m01 * py) * iz
        b0 = m01 * iz
        b1 = m11 * iz
        b2 = -(m01 * px + m11 * py) * iz
        _pose_rows(Jc, Jp, o, R, q0, q1, q2, a0, a1, a2, b0, b1, b2)
        _radial_rows(Jg, o, 0, f, d, r2, px, py)


@njit(cache=True)
def _rotation_vectors(R: np.ndarray) -> np.ndarray:
    out = np.empty((R.shape[0], 3))
    for i in range(R.shape[0]):
        out[i] = _rotation_vector(R[i])
    return out


def pose_params(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Poses R (N, 3, 3), t (N, 3) -> parameter rows (N, 6) ``[rvec, t]`` (stable up to pi)."""
    R = np.ascontiguousarray(R, np.float64).reshape(-1, 3, 3)
    return np.hstack([_rotation_vectors(R), np.asarray(t, np.float64).reshape(-1, 3)])


def poses_from_params(params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Parameter rows (N, >=6) -> R (N, 3, 3), t (N, 3)."""
    p = np.ascontiguousarray(params, np.float64)
    return _rotation_matrices(p), p[:, 3:6].copy()


class CameraModel:
    """Interface of a bundle-adjustment camera model (see the module docstring)."""

    n_params: int
    """Parameters per camera (and the size of a camera's tangent space)."""
    n_shared: int = 0
    """Parameters shared by every camera (0: none; see :meth:`evaluate_shared`)."""

    def evaluate(
        self, params: np.ndarray, points: np.ndarray, cam_idx: np.ndarray, pt_idx: np.ndarray,
        obs: np.ndarray, want_jac: bool,
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Residuals and Jacobians.

        params (C, n_params) float64, points (P, 3) float64, cam_idx/pt_idx (N,) int64 indices,
        obs (N, 2) float64 pixels. Returns r (N, 2) pixels, Jc (N, 2, n_params), Jp (N, 2, 3)
        (both None unless ``want_jac``).
        """
        raise NotImplementedError

    def evaluate_shared(
        self, params: np.ndarray, shared: np.ndarray, points: np.ndarray, cam_idx: np.ndarray, pt_idx: np.ndarray,
        obs: np.ndarray, want_jac: bool,
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """As :meth:`evaluate` with the shared parameters ``shared`` (n_shared,) float64; also returns
        Jg (N, 2, n_shared), the derivatives by them (None unless ``want_jac``)."""
        raise NotImplementedError

    def retract(self, params: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """Apply a tangent step: params (C, n_params), delta (C, n_params) -> new params."""
        return _retract(params, delta)


def _buffers(n: int, p: int, want_jac: bool):
    r = np.empty((n, 2))
    if want_jac:
        return r, np.empty((n, 2, p)), np.empty((n, 2, 3))
    return r, np.empty((1, 2, p)), np.empty((1, 2, 3))


class PinholeModel(CameraModel):
    """Known intrinsics per camera; parameters ``[rvec(3), t(3)]`` (world-to-camera, OpenCV axes).

    intrinsics: (C, 4) float64 rows ``fx, fy, cx, cy`` in pixels, or a (3, 3) K shared by all.
    """

    n_params = 6

    def __init__(self, intrinsics: np.ndarray, n_cameras: int | None = None) -> None:
        k = np.asarray(intrinsics, np.float64)
        if k.shape == (3, 3):
            if n_cameras is None:
                raise ValueError("a shared K needs n_cameras")
            k = np.tile([k[0, 0], k[1, 1], k[0, 2], k[1, 2]], (n_cameras, 1))
        if k.ndim != 2 or k.shape[1] != 4:
            raise ValueError(f"intrinsics must be (C, 4) or (3, 3), got {k.shape}")
        self.intrinsics = np.ascontiguousarray(k)

    def evaluate(self, params, points, cam_idx, pt_idx, obs, want_jac):
        r, Jc, Jp = _buffers(len(cam_idx), 6, want_jac)
        _pinhole_kernel(params, self.intrinsics, points, cam_idx, pt_idx, obs, want_jac, r, Jc, Jp)
        return (r, Jc, Jp) if want_jac else (r, None, None)


class BALModel(CameraModel):
    """The BAL camera: parameters ``[rvec(3), t(3), f, k1, k2]`` with BAL's axes (looks down -z)."""

    n_params = 9

    def evaluate(self, params, points, cam_idx, pt_idx, obs, want_jac):
        r, Jc, Jp = _buffers(len(cam_idx), 9, want_jac)
        _bal_kernel(params, points, cam_idx, pt_idx, obs, want_jac, r, Jc, Jp)
        return (r, Jc, Jp) if want_jac else (r, None, None)


class RadialModel(CameraModel):
    """Self-calibration: per camera ``[rvec(3), t(3)]`` (world-to-camera, OpenCV axes); shared by all
    cameras ``f, k1, k2`` (focal length in pixels, radial distortion of the normalised image point,
    OpenCV's k1, k2) and, with ``refine_centre``, the principal point ``cx, cy`` (pixels; five shared
    parameters); without it the principal point ``centre`` (2,) pixels stays fixed.

    The shared parameters are passed to :meth:`evaluate_shared` (the solver refines them);
    :meth:`evaluate` uses ``shared`` given here, for callers that only want residuals.
    """

    n_params = 6

    def __init__(self, centre: tuple[float, float] | np.ndarray, shared: np.ndarray | None = None,
                 refine_centre: bool = False) -> None:
        self.n_shared = 5 if refine_centre else 3
        self.centre = np.ascontiguousarray(centre, np.float64).reshape(2)
        self.shared = None if shared is None else np.ascontiguousarray(shared, np.float64).reshape(self.n_shared)

    def evaluate_shared(self, params, shared, points, cam_idx, pt_idx, obs, want_jac):
        n = len(cam_idx)
        g = self.n_shared
        r, Jc, Jp = _buffers(n, 6, want_jac)
        Jg = np.empty((n, 2, g)) if want_jac else np.empty((1, 2, g))
        _radial_kernel(params, np.ascontiguousarray(shared, np.float64), self.centre, points, cam_idx, pt_idx, obs,
                       want_jac, r, Jc, Jp, Jg)
        return (r, Jc, Jp, Jg) if want_jac else (r, None, None, None)

    def evaluate(self, params, points, cam_idx, pt_idx, obs, want_jac):
        if self.shared is None:
            raise ValueError("RadialModel.evaluate needs the shared parameters given to the constructor")
        r, Jc, Jp, _ = self.evaluate_shared(params, self.shared, points, cam_idx, pt_idx, obs, want_jac)
        return r, Jc, Jp
