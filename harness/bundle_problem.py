"""A bundle adjustment problem with known truth: cameras along a line looking at points 6-10 m ahead."""
from __future__ import annotations

import numpy as np

K = np.array([[400.0, 0, 319.5], [0, 400.0, 239.5], [0, 0, 1]])
"""The cameras' intrinsics (pixels): 640 x 480, f = 400."""


def _rotation(v: np.ndarray) -> np.ndarray:
    """The rotation (3, 3) of the axis-angle vector ``v`` (3,) radians (Rodrigues)."""
    th = np.linalg.norm(v)
    if th == 0:
        return np.eye(3)
    a = v / th
    A = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(th) * A + (1 - np.cos(th)) * A @ A


def line_of_cameras(n_cams: int = 6, n_pts: int = 250, seed: int = 0
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``n_cams`` cameras (intrinsics :data:`K`) 2.5 m along x, turned a few degrees, every one seeing all ``n_pts``
    points 6-10 m ahead; camera 0 at the origin, unturned. Returns the truth and its exact observations: R
    (n_cams, 3, 3) and t (n_cams, 3) world-to-camera, X (n_pts, 3) metres, ci and pj (n_cams * n_pts,) int64 (the
    camera and point of each observation), obs (n_cams * n_pts, 2) pixels."""
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(-3, 3, n_pts), rng.uniform(-2, 2, n_pts), rng.uniform(6, 10, n_pts)])
    R = np.stack([_rotation(rng.normal(0, 0.05, 3)) for _ in range(n_cams)])
    R[0] = np.eye(3)
    C = np.column_stack([np.linspace(0, 2.5, n_cams), rng.normal(0, 0.1, n_cams), rng.normal(0, 0.1, n_cams)])
    C[0] = 0
    t = -np.einsum("nij,nj->ni", R, C)
    ci = np.repeat(np.arange(n_cams), n_pts)
    pj = np.tile(np.arange(n_pts), n_cams)
    P = np.einsum("nij,nj->ni", R[ci], X[pj]) + t[ci]
    obs = P[:, :2] / P[:, 2:] @ K[:2, :2].T + K[:2, 2]
    return R, t, X, ci, pj, obs
