"""Poses for the frames outside the map (our addition after the paper's pipeline).

The paper's method maps the keyframes. COLMAP gives every image a pose, so the other frames are
registered afterwards against the final map, without changing it: the selected frames that are
not keyframes by their own tracks, and the decoded frames that frame selection left out (little
motion, blur, a frame step) by optical flow from the last selected frame before them. Each gets a
RANSAC PnP pose on its 2D points of mapped tracks, refined by Levenberg–Marquardt on the
inliers (pose only); a frame that cannot be registered keeps the reason.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .frames import Skipped
from .matching import forward_backward_mask, lk_flow
from .multiview import register_pnp

MIN_INLIERS = 12


@dataclass(frozen=True)
class SideView:
    """A decoded frame left out by selection, seen through the features of the last selected
    frame before it: ``keys`` (N,) int64 the tracker's feature keys (``TrackSet.raw_to_track``),
    ``xy`` (N, 2) float32 their positions in this frame (working-resolution pixels), ``after``
    the position of that selected frame in the sequence (-1 when none); ``failure`` says why
    there are no points."""

    index: int
    time: float | None
    name: str
    reason: str
    after: int
    keys: np.ndarray
    xy: np.ndarray
    failure: str | None = None


def follow_skipped(skipped: Skipped, last: tuple[np.ndarray, np.ndarray, np.ndarray] | None, after: int,
                   fb_threshold: float, window: int, levels: int, max_points: int = 400) -> SideView:
    """Follow the features of the last selected frame into a skipped one.

    ``last``: that frame's gray (H, W) uint8, feature keys (N,) and positions (N, 2) float32 (the
    tracker's :meth:`last_frame`); at most ``max_points`` of them, evenly spaced in the list, are
    followed by pyramidal LK and kept where the forward-backward error is <= ``fb_threshold`` px
    (a few hundred points pin a pose; a kept view holds about 5 kB however long the video).
    """
    def empty(failure: str) -> SideView:
        return SideView(skipped.index, skipped.time, skipped.name, skipped.reason, after,
                        np.zeros(0, np.int64), np.zeros((0, 2), np.float32), failure)

    if skipped.gray is None:
        return empty("not usable: " + skipped.reason)
    if last is None:
        return empty("no selected frame before it")
    if len(last[1]) == 0:
        return empty("the selected frame before it has no features to follow")
    gray0, keys, pts = last
    if len(keys) > max_points:
        pick = np.linspace(0, len(keys) - 1, max_points).round().astype(np.int64)
        keys, pts = keys[pick], pts[pick]
    end, ok = lk_flow(gray0, skipped.gray, pts, window, levels)
    ok[ok] = forward_backward_mask(gray0, skipped.gray, pts[ok], end[ok], fb_threshold, window, levels)
    return SideView(skipped.index, skipped.time, skipped.name, skipped.reason, after, keys[ok].astype(np.int64),
                    end[ok].astype(np.float32))


@dataclass(frozen=True)
class Located:
    """A frame's pose against the map: R (3, 3), t (3,) world-to-camera, or None with ``failure``;
    ``inliers`` of ``candidates`` 2D points of mapped tracks."""

    R: np.ndarray | None
    t: np.ndarray | None
    inliers: int
    candidates: int
    failure: str | None


def locate(X: np.ndarray, xy: np.ndarray, K: np.ndarray, threshold: float, min_inliers: int = MIN_INLIERS
           ) -> Located:
    """Pose of one frame from map points X (N, 3) seen at pixels xy (N, 2) (working resolution):
    RANSAC PnP (``threshold`` px), then LM on the inliers; fails below ``min_inliers``."""
    n = len(X)
    if n < min_inliers:
        return Located(None, None, 0, n, f"sees {n} mapped points (fewer than {min_inliers})")
    res = register_pnp(np.asarray(X, np.float64), np.asarray(xy, np.float64), K, threshold, min_inliers)
    if res is None:
        return Located(None, None, 0, n, f"no PnP pose with {min_inliers} inliers among {n} mapped points")
    R, t, inl = res
    return Located(R, t, int(inl.sum()), n, None)
