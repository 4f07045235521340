"""Two-view geometry with a known K (the paper's II-C and III-C).

Conventions: world-to-camera ``x_cam = R X + t``; "normalised" image points are ``K^-1 m``
(first two coordinates). The first camera of a pair is ``[I | 0]`` (the paper's ``P^0``).
"""
from __future__ import annotations

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix [v]x (3, 3) of a vector v (3,)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle (degrees) of Ra Rb^T for stacks (N, 3, 3) or single (3, 3) matrices."""
    M = np.asarray(Ra) @ np.swapaxes(np.asarray(Rb), -1, -2)
    c = np.clip((np.trace(M, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)
    return np.degrees(np.arccos(c))


def essential_from_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """E = [t]x R (3, 3) for the second camera [R | t] relative to [I | 0]."""
    return skew(np.asarray(t, np.float64)) @ np.asarray(R, np.float64)


def decompose_essential(E: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The four (R, t) candidates of an essential matrix by SVD; t (3,) has unit norm."""
    U, _, Vt = np.linalg.svd(E)
    if np.linalg.det(U) < 0:
        U = -U
    if np.linalg.det(Vt) < 0:
        Vt = -Vt
    Wm = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    t = U[:, 2]
    R1 = U @ Wm @ Vt
    R2 = U @ Wm.T @ Vt
    return [(R1, t), (R1, -t), (R2, t), (R2, -t)]


def triangulate_dlt(P0: np.ndarray, P1: np.ndarray, m0: np.ndarray, m1: np.ndarray) -> np.ndarray:
    """Linear triangulation of the paper's III-C for many points at once.

    Solves ``[[P0, -m0, 0], [P1, 0, -m1]] [X~; l0; l1] = 0`` (6x6) by SVD per point.
    P0, P1: (3, 4) projection matrices, or (N, 3, 4) stacks (one pair per point), in pixels with
    K included or normalised with K = I; m0, m1: (N, 2) matching image points in the same units. Returns X (N, 3) float64
    (NaN where the homogeneous solution is at infinity).
    """
    m0 = np.asarray(m0, np.float64).reshape(-1, 2)
    m1 = np.asarray(m1, np.float64).reshape(-1, 2)
    n = len(m0)
    A = np.zeros((n, 6, 6))
    A[:, :3, :4] = P0
    A[:, 3:, :4] = P1
    A[:, :2, 4] = -m0
    A[:, 2, 4] = -1.0
    A[:, 3:5, 5] = -m1
    A[:, 5, 5] = -1.0
    # Scale rows so that pixel-sized and unit-sized coefficients weigh alike.
    A /= np.linalg.norm(A, axis=2, keepdims=True)
    _, _, Vt = np.linalg.svd(A)
    h = Vt[:, -1, :4]
    with np.errstate(divide="ignore", invalid="ignore"):
        X = h[:, :3] / h[:, 3:4]
    X[~np.isfinite(X).all(axis=1)] = np.nan
    return X


def depths(R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Depth z (N,) of world points X (N, 3) in camera [R | t]."""
    return X @ R[2] + t[2]


def pose_from_essential(E: np.ndarray, x0: np.ndarray, x1: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Relative pose from E with the cheirality test.

    x0, x1: (N, 2) normalised points of cameras [I | 0] and [R | t]. Of the four SVD candidates
    the one with the most triangulated points in front of both cameras wins. Returns R (3, 3),
    t (3,) unit norm, and a (N,) bool mask of points in front of both cameras.
    """
    P0 = np.hstack([np.eye(3), np.zeros((3, 1))])
    best = None
    for R, t in decompose_essential(E):
        X = triangulate_dlt(P0, np.hstack([R, t[:, None]]), x0, x1)
        with np.errstate(invalid="ignore"):
            front = (X[:, 2] > 0) & (depths(R, t, X) > 0)
        if best is None or front.sum() > best[2].sum():
            best = (R, t, front)
    return best


def triangulation_angles_deg(C0: np.ndarray, C1: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Angle (degrees) at each X (N, 3) between the rays to centres C0, C1 ((3,) or (N, 3))."""
    a = C0 - X
    b = C1 - X
    cos = np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def project(K: np.ndarray, R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of world points X (N, 3) in the pinhole camera K [R | t]."""
    P = X @ R.T + t
    with np.errstate(divide="ignore", invalid="ignore"):
        p = P[:, :2] / P[:, 2:3]
    return p @ K[:2, :2].T + K[:2, 2]


def normalise(K: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) -> normalised coordinates (N, 2) (first two of K^-1 [m; 1])."""
    m = np.asarray(m, np.float64).reshape(-1, 2)
    y = (m[:, 1] - K[1, 2]) / K[1, 1]
    x = (m[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return np.stack([x, y], axis=1)


def camera_centre(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Centre -R^T t (3,) of camera [R | t]; stacks (N, 3, 3), (N, 3) give (N, 3)."""
    return -np.einsum("...ji,...j->...i", R, t)
