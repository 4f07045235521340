"""Multi-view steps of the incremental reconstruction: keyframes by parallax, the initial pair
(E, pose by SVD with cheirality, DLT triangulation: the paper's III-C), registering a new frame
by PnP into the shared scale, and triangulating tracks between registered frames."""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .geometry import camera_centre, depths, normalise, pose_from_essential, project, triangulate_dlt
from .geometry import triangulation_angles_deg
from .matching import estimate_essential
from .tracks import TrackSet


def select_keyframes(tracks: TrackSet, width: int, parallax: float, min_shared: float = 0.5) -> np.ndarray:
    """Keyframe positions (K,) int64 in the frame sequence, starting with frame 0.

    A frame becomes a keyframe when the tracks it shares with the last keyframe moved by a
    median of ``parallax * width`` pixels, or when fewer than ``min_shared`` of the last
    keyframe's tracks are still seen.
    """
    if tracks.n_frames == 0:
        return np.zeros(0, np.int64)
    keys = [0]
    sl = tracks.frame_slice(0)
    kt, kxy = tracks.obs_track[sl], tracks.obs_xy[sl]
    for f in range(1, tracks.n_frames):
        sl = tracks.frame_slice(f)
        t, xy = tracks.obs_track[sl], tracks.obs_xy[sl]
        if len(t) == 0:
            continue
        _, ia, ib = np.intersect1d(kt, t, assume_unique=True, return_indices=True)
        moved = float(np.median(np.linalg.norm(kxy[ia] - xy[ib], axis=1))) if len(ia) else 0.0
        if moved >= parallax * width or len(ia) < min_shared * len(kt):
            keys.append(f)
            kt, kxy = t, xy
    return np.asarray(keys, np.int64)


@dataclass(frozen=True)
class TwoView:
    """The initial pair: second camera [R | t] (|t| = 1) relative to [I | 0]; points X (N, 3)
    for all input matches, ``good`` (N,) those in front of both cameras, reprojecting within the
    threshold, with enough triangulation angle; ``median_angle`` (degrees) over the good ones."""

    R: np.ndarray
    t: np.ndarray
    X: np.ndarray
    good: np.ndarray
    median_angle: float


def two_view(m0: np.ndarray, m1: np.ndarray, K: np.ndarray, ransac_threshold: float, max_error: float,
             min_angle: float) -> TwoView | None:
    """Relative pose and points of two frames from matches m0 <-> m1 (N, 2) pixels; None when
    no essential matrix is found.

    The pose from E (SVD + cheirality) competes with the decompositions of a RANSAC homography:
    over a nearly flat scene (a nadir drone survey) E has a twin solution that fits the plane as
    well, and RANSAC may return it. The candidate under which most matches triangulate in front
    of both cameras within ``2 * ransac_threshold`` pixels wins.
    """
    E, inl = estimate_essential(m0, m1, K, ransac_threshold)
    if E is None or inl.sum() < 8:
        return None
    R, t, _ = pose_from_essential(E, normalise(K, m0[inl]), normalise(K, m1[inl]))
    candidates = [(R, t)]
    H, _ = cv2.findHomography(m0, m1, cv2.RANSAC, 2.0 * ransac_threshold)
    if H is not None:
        _, Rs, ts, _ = cv2.decomposeHomographyMat(H, K)
        candidates += [(Rh, th.ravel() / np.linalg.norm(th)) for Rh, th in zip(Rs, ts) if np.linalg.norm(th) > 1e-9]
    P0 = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    best = None
    for Rc, tc in candidates:
        X = triangulate_dlt(P0, K @ np.hstack([Rc, tc[:, None]]), m0, m1)
        ok = _valid(X, [(np.eye(3), np.zeros(3), m0), (Rc, tc, m1)], K, 2.0 * ransac_threshold)
        if best is None or ok.sum() > best[3].sum():
            best = (Rc, tc, X, ok)
    R, t, X, ok = best
    good = ok & _valid(X, [(np.eye(3), np.zeros(3), m0), (R, t, m1)], K, max_error)
    ang = triangulation_angles_deg(np.zeros(3), camera_centre(R, t), np.nan_to_num(X))
    good &= ang >= min_angle
    return TwoView(R, t, X, good, float(np.median(ang[good])) if good.any() else 0.0)


def _valid(X: np.ndarray, views: list[tuple[np.ndarray, np.ndarray, np.ndarray]], K: np.ndarray,
           max_error: float) -> np.ndarray:
    ok = np.isfinite(X).all(axis=1)
    Xs = np.nan_to_num(X)
    for R, t, m in views:
        with np.errstate(invalid="ignore"):
            ok &= depths(R, t, Xs) > 0
            ok &= np.linalg.norm(project(K, R, t, Xs) - m, axis=1) <= max_error
    return ok


def register_pnp(X: np.ndarray, m: np.ndarray, K: np.ndarray, threshold: float, min_inliers: int = 12
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Pose of a new frame from 3D points X (N, 3) seen at pixels m (N, 2): RANSAC PnP, then
    Levenberg–Marquardt on the inliers. Returns R (3, 3), t (3,), inlier mask (N,) or None."""
    if len(X) < max(min_inliers, 6):
        return None
    ok, rvec, tvec, idx = cv2.solvePnPRansac(
        np.ascontiguousarray(X, np.float64), np.ascontiguousarray(m, np.float64), K, None,
        iterationsCount=300, reprojectionError=float(threshold), confidence=0.999, flags=cv2.SOLVEPNP_AP3P)
    if not ok or idx is None or len(idx) < min_inliers:
        return None
    inl = np.zeros(len(X), bool)
    inl[idx.ravel()] = True
    rvec, tvec = cv2.solvePnPRefineLM(X[inl].astype(np.float64), m[inl].astype(np.float64), K, None, rvec, tvec)
    R = cv2.Rodrigues(rvec)[0]
    t = tvec.ravel()
    err = np.linalg.norm(project(K, R, t, X) - m, axis=1)
    inl = (err <= threshold) & (depths(R, t, X) > 0)
    if inl.sum() < min_inliers:
        return None
    return R, t, inl


def triangulate_pairs(K: np.ndarray, R0: np.ndarray, t0: np.ndarray, m0: np.ndarray, R1: np.ndarray,
                      t1: np.ndarray, m1: np.ndarray, max_error: float, min_angle: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """DLT points from observations m0 (N, 2) in cameras (R0, t0) and m1 in (R1, t1).

    Poses are (3, 3)/(3,) or stacks (N, 3, 3)/(N, 3). Returns X (N, 3) and a (N,) bool mask of
    points in front of both cameras, within ``max_error`` pixels, with an angle >= ``min_angle``.
    """
    n = len(m0)
    R0 = np.broadcast_to(R0, (n, 3, 3))
    R1 = np.broadcast_to(R1, (n, 3, 3))
    t0 = np.broadcast_to(t0, (n, 3))
    t1 = np.broadcast_to(t1, (n, 3))
    P0 = K @ np.concatenate([R0, t0[:, :, None]], axis=2)
    P1 = K @ np.concatenate([R1, t1[:, :, None]], axis=2)
    X = triangulate_dlt(P0, P1, m0, m1)
    Xs = np.nan_to_num(X)
    ok = np.isfinite(X).all(axis=1)
    for R, t, m in ((R0, t0, m0), (R1, t1, m1)):
        P = np.einsum("nij,nj->ni", R, Xs) + t
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = P[:, :2] / P[:, 2:3] @ K[:2, :2].T + K[:2, 2]
            ok &= (P[:, 2] > 0) & (np.linalg.norm(uv - m, axis=1) <= max_error)
    ok &= triangulation_angles_deg(camera_centre(R0, t0), camera_centre(R1, t1), Xs) >= min_angle
    return X, ok
