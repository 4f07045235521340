"""Correspondences between two frames.

- The paper's III-A: FAST corners in frame k are followed to frame k+1 by pyramidal
  Lucas–Kanade optical flow; a flow whose end point is farther than a threshold from every FAST
  corner of frame k+1 is an outlier (:func:`fast_rule_mask`). A forward–backward flow check
  and RANSAC on the essential matrix follow.
- The comparison: SIFT descriptors, Lowe's ratio test, RANSAC on the essential matrix.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

_LK_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)


@dataclass(frozen=True)
class PairStats:
    """Counts of one frame pair, each stage keeping a subset of the previous one.

    ``proposed``: correspondences the matcher proposes (LK flows that converged, or SIFT
    matches passing the ratio test); ``after_fb`` and ``after_rule`` the flows left after the
    forward–backward check and the paper's FAST rule (equal to ``proposed`` for SIFT);
    ``inliers``: consistent with the RANSAC essential matrix. ``bridged`` (FAST+LK tracking):
    tracks that only the paper's rule rejected in this pair and that go on unrecorded.
    """

    frame0: int
    frame1: int
    proposed: int
    after_fb: int
    after_rule: int
    inliers: int
    bridged: int = 0

    @property
    def inlier_ratio(self) -> float:
        """Fraction of the matcher's final candidates that RANSAC keeps (1.0 when none)."""
        return self.inliers / self.after_rule if self.after_rule else 1.0


def fast_rule_mask(end_points: np.ndarray, corners: np.ndarray, threshold: float) -> np.ndarray:
    """The paper's outlier rule: True where a flow end point (N, 2) lies within ``threshold``
    pixels of its nearest FAST corner (M, 2) of the next frame."""
    if len(end_points) == 0 or len(corners) == 0:
        return np.zeros(len(end_points), bool)
    dist, _ = cKDTree(corners).query(end_points, k=1, distance_upper_bound=threshold)
    return np.isfinite(dist)


def global_shift(gray0: np.ndarray, gray1: np.ndarray, size: int = 256) -> tuple[np.ndarray, float]:
    """Dominant image translation from gray0 to gray1 by phase correlation on copies at most
    ``size`` pixels wide: the shift (2,) float32 in pixels of gray0 and the correlation peak
    (near 0 when no single translation explains the motion, e.g. strong rotation)."""
    h, w = gray0.shape
    s = min(1.0, size / max(h, w))
    a = cv2.resize(gray0, None, fx=s, fy=s, interpolation=cv2.INTER_AREA).astype(np.float32)
    b = cv2.resize(gray1, None, fx=s, fy=s, interpolation=cv2.INTER_AREA).astype(np.float32)
    win = cv2.createHanningWindow(a.shape[::-1], cv2.CV_32F)
    (dx, dy), response = cv2.phaseCorrelate(a, b, win)
    return np.array([dx / s, dy / s], np.float32), float(response)


def global_motion(gray0: np.ndarray, gray1: np.ndarray, size: int = 480) -> np.ndarray | None:
    """A similarity transform (2, 3) float64 mapping pixels of gray0 to gray1, from ORB matches
    on copies at most ``size`` pixels wide (RANSAC); None when it cannot be estimated.

    It seeds the optical flow when frames are far apart or turned (stills, fast turns).
    """
    s = min(1.0, size / max(gray0.shape))
    a = cv2.resize(gray0, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
    b = cv2.resize(gray1, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
    orb = cv2.ORB_create(nfeatures=1500)
    ka, da = orb.detectAndCompute(a, None)
    kb, db = orb.detectAndCompute(b, None)
    if da is None or db is None or len(ka) < 10 or len(kb) < 10:
        return None
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(da, db)
    if len(matches) < 10:
        return None
    pa = np.array([ka[m.queryIdx].pt for m in matches], np.float64)
    pb = np.array([kb[m.trainIdx].pt for m in matches], np.float64)
    A, inl = cv2.estimateAffinePartial2D(pa, pb, method=cv2.RANSAC, ransacReprojThreshold=3.0)
    if A is None or inl is None or inl.sum() < 10:
        return None
    # Back to full resolution: x1 = (A (s x0) ) / s, with the translation in thumbnail pixels.
    A = A.copy()
    A[:, 2] /= s
    return A


def lk_flow(gray0: np.ndarray, gray1: np.ndarray, pts0: np.ndarray, window: int = 21, levels: int = 4,
            guess: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pyramidal Lucas–Kanade from gray0 to gray1 (H, W) uint8.

    pts0: (N, 2) float32; ``guess`` (N, 2) initial end points. Returns end points (N, 2)
    float32 and a (N,) bool mask of flows that converged inside the image.
    """
    if len(pts0) == 0:
        return np.zeros((0, 2), np.float32), np.zeros(0, bool)
    p0 = np.ascontiguousarray(pts0, np.float32).reshape(-1, 1, 2)
    flags = 0
    p1 = None
    if guess is not None:
        p1 = np.ascontiguousarray(guess, np.float32).reshape(-1, 1, 2).copy()
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    p1, status, _ = cv2.calcOpticalFlowPyrLK(gray0, gray1, p0, p1, winSize=(window, window), maxLevel=levels,
                                             criteria=_LK_CRITERIA, flags=flags)
    p1 = p1.reshape(-1, 2)
    h, w = gray1.shape
    inside = (p1[:, 0] >= 0) & (p1[:, 1] >= 0) & (p1[:, 0] <= w - 1) & (p1[:, 1] <= h - 1)
    return p1, status.ravel().astype(bool) & inside


def forward_backward_mask(gray0: np.ndarray, gray1: np.ndarray, pts0: np.ndarray, pts1: np.ndarray,
                          threshold: float, window: int = 21, levels: int = 4) -> np.ndarray:
    """True where flowing pts1 (N, 2) back from gray1 lands within ``threshold`` px of pts0."""
    back, ok = lk_flow(gray1, gray0, pts1, window, levels, guess=pts0)
    return ok & (np.linalg.norm(back - pts0, axis=1) <= threshold)


def estimate_essential(m0: np.ndarray, m1: np.ndarray, K: np.ndarray, threshold: float,
                       confidence: float = 0.999) -> tuple[np.ndarray | None, np.ndarray]:
    """RANSAC essential matrix of matches m0 <-> m1 (N, 2) pixels: five-point minimal sets,
    local optimisation and a final fit on all inliers (OpenCV's USAC_ACCURATE).

    ``threshold`` is the epipolar distance in pixels. Returns E (3, 3) or None, and the inlier
    mask (N,) bool (all False when fewer than eight matches or no model was found).
    """
    n = len(m0)
    if n < 8:
        return None, np.zeros(n, bool)
    E, mask = cv2.findEssentialMat(np.ascontiguousarray(m0, np.float64), np.ascontiguousarray(m1, np.float64),
                                   K, method=cv2.USAC_ACCURATE, prob=confidence, threshold=threshold)
    if E is None or mask is None or E.shape[0] < 3:
        return None, np.zeros(n, bool)
    return E[:3], mask.ravel().astype(bool)


def sampson_distance(E: np.ndarray, K: np.ndarray, m0: np.ndarray, m1: np.ndarray) -> np.ndarray:
    """First-order geometric distance (N,) in pixels of matches m0 <-> m1 (N, 2) pixels from the
    epipolar geometry of the essential matrix E (3, 3) with intrinsics K (3, 3)."""
    Kinv = np.linalg.inv(K)
    F = Kinv.T @ E @ Kinv
    x0 = np.column_stack([m0, np.ones(len(m0))])
    x1 = np.column_stack([m1, np.ones(len(m1))])
    Fx0 = x0 @ F.T
    Ftx1 = x1 @ F
    num = np.einsum("ij,ij->i", x1, Fx0)
    den = Fx0[:, 0] ** 2 + Fx0[:, 1] ** 2 + Ftx1[:, 0] ** 2 + Ftx1[:, 1] ** 2
    return np.abs(num) / np.sqrt(np.maximum(den, 1e-300))


def essential_inliers(m0: np.ndarray, m1: np.ndarray, K: np.ndarray, threshold: float) -> np.ndarray:
    """Inlier mask (N,) of matches m0 <-> m1 (pixels) under a RANSAC essential matrix."""
    return estimate_essential(m0, m1, K, threshold)[1]


@dataclass(frozen=True)
class FlowResult:
    """FAST+LK correspondences of one pair: end points (N, 2) for all input points and the
    masks of each stage (N,) bool, each a subset of the previous. ``consistent`` (N,) bool:
    flows passing the forward-backward check that also fit the RANSAC essential matrix,
    whether or not the paper's rule kept them (a superset of ``inliers``)."""

    end_points: np.ndarray
    converged: np.ndarray
    after_fb: np.ndarray
    after_rule: np.ndarray
    inliers: np.ndarray
    consistent: np.ndarray


def fast_lk_match(gray0: np.ndarray, gray1: np.ndarray, pts0: np.ndarray, corners1: np.ndarray, K: np.ndarray,
                  rule_threshold: float = 2.0, fb_threshold: float = 1.0, ransac_threshold: float = 1.0,
                  window: int = 21, levels: int = 4, motion: np.ndarray | None = None) -> FlowResult:
    """The paper's III-A for points pts0 (N, 2) of gray0 followed into gray1.

    corners1: FAST corners (M, 2) of gray1; K (3, 3) for the RANSAC E. ``motion`` (2, 3), an
    approximate similarity from gray0 to gray1 (e.g. :func:`global_motion`), seeds the flow;
    when it turns the image by more than 10 degrees gray1 is first warped back onto gray0, the
    flow runs between the aligned images and its end points are mapped back (LK itself only
    follows translations).
    """
    target, guess, back = gray1, None, None
    if motion is not None:
        angle = abs(np.degrees(np.arctan2(motion[1, 0], motion[0, 0])))
        if angle > 10.0:
            h, w = gray0.shape
            target = cv2.warpAffine(gray1, motion, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
            back = motion
        else:
            guess = (pts0 @ motion[:, :2].T + motion[:, 2]).astype(np.float32)
    p1, ok = lk_flow(gray0, target, pts0, window, levels, guess)
    fb = ok.copy()
    if ok.any():
        fb[ok] = forward_backward_mask(gray0, target, pts0[ok], p1[ok], fb_threshold, window, levels)
    if back is not None:
        p1 = (p1 @ back[:, :2].T + back[:, 2]).astype(np.float32)
        h, w = gray1.shape
        inside = (p1[:, 0] >= 0) & (p1[:, 1] >= 0) & (p1[:, 0] <= w - 1) & (p1[:, 1] <= h - 1)
        ok &= inside
        fb &= inside
    rule = fb.copy()
    rule[fb] = fast_rule_mask(p1[fb], corners1, rule_threshold)
    inl = rule.copy()
    E, inl[rule] = estimate_essential(pts0[rule], p1[rule], K, ransac_threshold)
    consistent = inl.copy()
    if E is not None:
        consistent[fb] = sampson_distance(E, K, pts0[fb], p1[fb]) <= ransac_threshold
        consistent |= inl
    return FlowResult(p1, ok, fb, rule, inl, consistent)


def sift_ratio_matches(desc0: np.ndarray, desc1: np.ndarray, ratio: float = 0.8) -> np.ndarray:
    """Lowe's ratio test: pairs (M, 2) int64 of indices (i in desc0, j in desc1)."""
    if len(desc0) < 2 or len(desc1) < 2:
        return np.zeros((0, 2), np.int64)
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(desc0, desc1, k=2)
    pairs = [(m.queryIdx, m.trainIdx) for m, n in (x for x in knn if len(x) == 2) if m.distance < ratio * n.distance]
    return np.array(pairs, np.int64).reshape(-1, 2)


def sift_ratio_matches_flann(desc0: np.ndarray, desc1: np.ndarray, ratio: float = 0.8, checks: int = 64
                             ) -> np.ndarray:
    """:func:`sift_ratio_matches` by FLANN's randomised k-d trees (4 trees, ``checks`` leaves): approximate, a
    few matches fewer, and many times faster than the brute force on thousands of descriptors (a survey matches
    thousands of pairs)."""
    if len(desc0) < 2 or len(desc1) < 2:
        return np.zeros((0, 2), np.int64)
    flann = cv2.FlannBasedMatcher({"algorithm": 1, "trees": 4}, {"checks": checks})
    knn = flann.knnMatch(np.ascontiguousarray(desc0, np.float32), np.ascontiguousarray(desc1, np.float32), k=2)
    pairs = [(m.queryIdx, m.trainIdx) for m, n in (x for x in knn if len(x) == 2) if m.distance < ratio * n.distance]
    return np.array(pairs, np.int64).reshape(-1, 2)
