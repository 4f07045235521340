"""Trajectory accuracy against ground truth: Sim(3) alignment (Umeyama), ATE, rotation error."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import rotation_angle_deg


@dataclass(frozen=True)
class Sim3:
    """``y = s R x + t``: scale s, rotation R (3, 3), translation t (3,)."""

    s: float
    R: np.ndarray
    t: np.ndarray

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Points (N, 3) -> (N, 3)."""
        return self.s * np.asarray(x) @ self.R.T + self.t


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> Sim3:
    """Least-squares similarity taking src (N, 3) onto dst (N, 3), N >= 3 (Umeyama 1991)."""
    src = np.asarray(src, np.float64)
    dst = np.asarray(dst, np.float64)
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    cov = b.T @ a / len(src)
    U, d, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    var = (a * a).sum() / len(src)
    s = float(np.trace(np.diag(d) @ S) / var) if with_scale and var > 0 else 1.0
    return Sim3(s, R, mu_d - s * R @ mu_s)


@dataclass(frozen=True)
class TrajectoryError:
    """ATE (RMSE of aligned centres, ground-truth units), max, mean rotation error (degrees)."""

    ate_rmse: float
    ate_max: float
    rotation_mean_deg: float | None
    n: int
    alignment: Sim3


def trajectory_error(C_est: np.ndarray, C_gt: np.ndarray, R_est: np.ndarray | None = None,
                     R_gt: np.ndarray | None = None) -> TrajectoryError:
    """ATE after Sim(3) alignment of estimated centres (N, 3) to ground truth (N, 3).

    With world-to-camera rotations R_est, R_gt (N, 3, 3) also the mean rotation error
    ``angle(R_gt_i, R_est_i A^T)`` where the world rotation A best aligns the orientations
    themselves (centres on a nearly straight or flat path leave the Sim(3) rotation loose).
    """
    sim = umeyama(C_est, C_gt)
    err = np.linalg.norm(sim.apply(C_est) - C_gt, axis=1)
    rot = None
    if R_est is not None and R_gt is not None:
        A = rotation_alignment(np.asarray(R_est), np.asarray(R_gt))
        rot = float(np.mean(rotation_angle_deg(R_gt, np.asarray(R_est) @ A.T)))
    return TrajectoryError(float(np.sqrt(np.mean(err**2))), float(err.max()), rot, len(err), sim)


def rotation_alignment(R_est: np.ndarray, R_gt: np.ndarray) -> np.ndarray:
    """The rotation A (3, 3) with ``R_est_i A^T ~ R_gt_i`` for stacks (N, 3, 3) (chordal mean)."""
    M = np.einsum("nji,njk->ik", R_est, R_gt)  # sum of R_est_i^T R_gt_i = sum of A^T
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return (U @ D @ Vt).T
