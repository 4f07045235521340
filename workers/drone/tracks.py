"""Feature tracks across the selected frames.

:class:`FlowTracker` is the paper's method run along the sequence: FAST corners start tracks,
Lucas–Kanade flow extends them frame to frame, and the III-A rule (plus a forward–backward
check and RANSAC on E) rejects doubtful end points; new FAST corners refill the empty parts of the
image. A track whose end point fails only the paper's rule (its flow passed the forward-backward
check and fits the pair's essential matrix) is not recorded in that frame but keeps being
followed for up to ``max_track_gap`` frames in a row: under sensor noise and blur a FAST corner
is often missed in one frame and found again in the next, and ending the track there would cut
every track short. :class:`SiftTracker` is the comparison: SIFT matched with the next
few frames (ratio test, RANSAC on E), tracks joined as connected components.

Both take frames one at a time (:meth:`add`) and return a :class:`TrackSet`.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .features import fast_corners_adaptive, sift_features, spread
from .frames import Frame
from .matching import (FlowResult, PairStats, essential_inliers, fast_lk_match, global_motion, global_shift,
                       sift_ratio_matches)
from .params import ReconstructionParams

_MIN_PEAK = 0.15  # phase-correlation peak below which the shift is not trusted as the motion


@dataclass
class TrackSet:
    """Observations of tracks, sorted by frame then track.

    obs_frame (M,) int64 position of the frame in the selected sequence; obs_track (M,) int64
    track ids 0..n_tracks-1; obs_xy (M, 2) float64 pixels (working resolution);
    obs_rgb (M, 3) uint8 BGR colour at the observation; pairs: statistics per matched pair;
    raw_to_track (R,) int64: the tracker's own key of a feature (see :meth:`FlowTracker.last_frame`)
    -> track id, -1 for features in no kept track.
    """

    obs_frame: np.ndarray
    obs_track: np.ndarray
    obs_xy: np.ndarray
    obs_rgb: np.ndarray
    n_frames: int
    pairs: list[PairStats]
    raw_to_track: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def n_tracks(self) -> int:
        return int(self.obs_track.max()) + 1 if len(self.obs_track) else 0

    def frame_slice(self, f: int) -> slice:
        """Rows of frame f (observations are sorted by frame)."""
        lo, hi = np.searchsorted(self.obs_frame, [f, f + 1])
        return slice(int(lo), int(hi))


def tracks_from_observations(frames: list[np.ndarray], tracks: list[np.ndarray], xys: list[np.ndarray],
                             rgbs: list[np.ndarray], n_frames: int, pairs: list[PairStats]) -> TrackSet:
    """Assemble observations (lists of per-source arrays: frame positions (n,) int, track ids (n,) int, pixels
    (n, 2), colours (n, 3) uint8 BGR), keep tracks seen in at least two frames, renumber them; the TrackSet's
    ``raw_to_track`` maps the given track ids (0..max) to the new ones."""
    if not frames:
        return TrackSet(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 3), np.uint8),
                        n_frames, pairs)
    f = np.concatenate(frames).astype(np.int64)
    t = np.concatenate(tracks).astype(np.int64)
    xy = np.concatenate(xys).astype(np.float64)
    rgb = np.concatenate(rgbs)
    _, inv, counts = np.unique(t, return_inverse=True, return_counts=True)
    keep = counts[inv] >= 2
    kept, t_new = np.unique(t[keep], return_inverse=True)
    raw_to_track = np.full(int(t.max()) + 1 if len(t) else 0, -1, np.int64)
    raw_to_track[kept] = np.arange(len(kept))
    f, xy, rgb = f[keep], xy[keep], rgb[keep]
    order = np.lexsort((t_new, f))
    return TrackSet(f[order], t_new[order].astype(np.int64), xy[order], rgb[order], n_frames, pairs, raw_to_track)


def colours_at(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The colours (N, 3) uint8 BGR of ``image`` (H, W, 3) at the pixels nearest ``xy`` (N, 2)."""
    h, w = image.shape[:2]
    u = np.clip(np.rint(xy[:, 0]).astype(np.int64), 0, w - 1)
    v = np.clip(np.rint(xy[:, 1]).astype(np.int64), 0, h - 1)
    return image[v, u]


class FlowTracker:
    """FAST + pyramidal LK tracking with the paper's outlier rule (see the module docstring)."""

    def __init__(self, K: np.ndarray, params: ReconstructionParams) -> None:
        self.K = np.asarray(K, np.float64)
        self.p = params
        self.prev: np.ndarray | None = None
        self.pts = np.zeros((0, 2), np.float32)
        self.ids = np.zeros(0, np.int64)
        self.misses = np.zeros(0, np.int64)  # frames in a row each live track's end point failed the rule
        self.next_id = 0
        self.n = 0
        self._f: list[np.ndarray] = []
        self._t: list[np.ndarray] = []
        self._xy: list[np.ndarray] = []
        self._rgb: list[np.ndarray] = []
        self.pairs: list[PairStats] = []

    def _record(self, frame: Frame, pts: np.ndarray, ids: np.ndarray) -> None:
        self._f.append(np.full(len(ids), self.n, np.int64))
        self._t.append(ids)
        self._xy.append(pts.astype(np.float64))
        self._rgb.append(colours_at(frame.image, pts))

    def add(self, frame: Frame) -> None:
        """Track into ``frame`` (the next selected frame)."""
        p = self.p
        corners = fast_corners_adaptive(frame.gray, p.fast_threshold, 2 * p.max_features)
        if self.prev is not None and len(self.pts):
            res = fast_lk_match(self.prev, frame.gray, self.pts, corners, self.K, p.outlier_threshold,
                                p.fb_threshold, p.ransac_threshold, p.lk_window, p.lk_levels,
                                motion=self._motion(frame.gray))
            seen = self._follow(res)
            self.pairs.append(PairStats(self.n - 1, self.n, int(res.converged.sum()), int(res.after_fb.sum()),
                                        int(res.after_rule.sum()), int(res.inliers.sum()), int((~seen).sum())))
            self._record(frame, self.pts[seen], self.ids[seen])
        # Refill: FAST corners of this frame in grid cells no live track occupies.
        room = p.max_features - len(self.pts)
        if room > 0:
            new = corners[spread(corners, p.feature_spacing, room, self.pts, frame.gray.shape)]
            new_ids = np.arange(self.next_id, self.next_id + len(new), dtype=np.int64)
            self.next_id += len(new)
            self._record(frame, new, new_ids)
            self.pts = np.vstack([self.pts, new]).astype(np.float32)
            self.ids = np.concatenate([self.ids, new_ids])
            self.misses = np.concatenate([self.misses, np.zeros(len(new), np.int64)])
        self.prev = frame.gray
        self.n += 1

    def _follow(self, res: FlowResult) -> np.ndarray:
        """Keep the tracks that go on after a matched pair: the inliers, and the flows that only
        the paper's rule rejected while the track has not missed ``max_track_gap`` frames in a
        row yet. Returns (N_kept,) bool: True where the new end point is an inlier (recorded)."""
        bridged = res.consistent & ~res.inliers & (self.misses < self.p.max_track_gap)
        keep = res.inliers | bridged
        seen = res.inliers[keep]
        self.pts = res.end_points[keep]
        self.ids = self.ids[keep]
        self.misses = np.where(seen, 0, self.misses[keep] + 1)
        return seen

    def last_frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The last added frame's gray (H, W) uint8 and its live features: keys (N,) int64 (raw
        track ids, see ``TrackSet.raw_to_track``) and positions (N, 2) float32; None before any."""
        if self.prev is None:
            return None
        return self.prev, self.ids, self.pts

    def _motion(self, gray: np.ndarray) -> np.ndarray | None:
        """Approximate image motion (2, 3) from the previous frame: a phase-correlation shift
        when it is clear and small (video), else a similarity from ORB matches (stills, turns)."""
        shift, peak = global_shift(self.prev, gray)
        if peak >= _MIN_PEAK and np.linalg.norm(shift) < 0.05 * max(gray.shape):
            return np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]]])
        return global_motion(self.prev, gray)

    def result(self) -> TrackSet:
        """All tracks seen in at least two frames."""
        return tracks_from_observations(self._f, self._t, self._xy, self._rgb, self.n, self.pairs)


class SiftTracker:
    """SIFT + ratio test + RANSAC on E against the next ``match_window`` frames."""

    def __init__(self, K: np.ndarray, params: ReconstructionParams) -> None:
        self.K = np.asarray(K, np.float64)
        self.p = params
        self.window: deque[tuple[int, np.ndarray, np.ndarray]] = deque(maxlen=params.match_window)
        self.offsets: list[int] = []
        self.n_nodes = 0
        self._xy: list[np.ndarray] = []
        self._rgb: list[np.ndarray] = []
        self._edges: list[tuple[np.ndarray, np.ndarray]] = []
        self.pairs: list[PairStats] = []
        self.n = 0
        self.prev: np.ndarray | None = None

    def add(self, frame: Frame) -> None:
        """Extract SIFT in ``frame`` and match it with the previous frames of the window."""
        kp, desc = sift_features(frame.gray, 2 * self.p.max_features)
        off = self.n_nodes
        for j, kp0, desc0 in self.window:
            m = sift_ratio_matches(desc0, desc, self.p.sift_ratio)
            inl = essential_inliers(kp0[m[:, 0]], kp[m[:, 1]], self.K, self.p.ransac_threshold)
            self.pairs.append(PairStats(j, self.n, len(m), len(m), len(m), int(inl.sum())))
            self._edges.append((self.offsets[j] + m[inl, 0], off + m[inl, 1]))
        self.window.append((self.n, kp, desc))
        self.offsets.append(off)
        self.n_nodes += len(kp)
        self._xy.append(kp.astype(np.float64))
        self._rgb.append(colours_at(frame.image, kp))
        self.prev = frame.gray
        self.n += 1

    def last_frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The last added frame's gray (H, W) uint8, its keypoints' keys (N,) int64 (node ids,
        see ``TrackSet.raw_to_track``) and positions (N, 2) float32; None before any frame."""
        if self.prev is None:
            return None
        off = self.offsets[-1]
        return self.prev, np.arange(off, off + len(self._xy[-1]), dtype=np.int64), self._xy[-1].astype(np.float32)

    def result(self) -> TrackSet:
        """Tracks = connected components of the match graph without two points in one frame."""
        if not self._edges or self.n_nodes == 0:
            return tracks_from_observations([], [], [], [], self.n, self.pairs)
        a = np.concatenate([e[0] for e in self._edges])
        b = np.concatenate([e[1] for e in self._edges])
        g = coo_matrix((np.ones(len(a)), (a, b)), shape=(self.n_nodes, self.n_nodes))
        _, label = connected_components(g, directed=False)
        node_frame = np.repeat(np.arange(self.n), np.diff(self.offsets + [self.n_nodes]))
        matched = np.zeros(self.n_nodes, bool)
        matched[a] = matched[b] = True
        # A component holding two points of one frame joins different scene points: drop it.
        key = label.astype(np.int64) * (self.n + 1) + node_frame
        _, first, counts = np.unique(key[matched], return_index=True, return_counts=True)
        bad = np.unique(label[matched][first[counts > 1]])
        keep = matched & ~np.isin(label, bad)
        xy = np.concatenate(self._xy)
        rgb = np.concatenate(self._rgb)
        out = tracks_from_observations([node_frame[keep]], [label[keep]], [xy[keep]], [rgb[keep]], self.n, self.pairs)
        # Keys of this tracker are nodes (keypoints), not component labels.
        node_track = np.full(self.n_nodes, -1, np.int64)
        node_track[keep] = out.raw_to_track[label[keep]]
        out.raw_to_track = node_track
        return out
