"""The incremental reconstruction pipeline (the paper's section III, sequence-wide).

media -> selected frames -> tracks (FAST+LK with the III-A rule, or SIFT) -> keyframes by
parallax -> initial pair (E, pose, DLT: III-C) -> next keyframes by PnP in the same scale, new
tracks triangulated, local bundle adjustments -> global bundle adjustment (eq. 5) with outliers
removed between rounds -> the selected frames that are not keyframes located by PnP against
the map, then (``joint_ba``) refined together with it by a final bundle adjustment over their
tracked observations -> the decoded frames selection left out located by PnP against the final
map, followed by optical flow from the selected frame before them (:mod:`workers.drone.localise`).

Without given intrinsics (a :class:`~workers.drone.selfcal.FocalPrior` passed to :func:`reconstruct`)
the global bundle adjustments also refine one focal length, radial distortion and principal point shared by
every frame (:class:`~workers.drone.camera_models.RadialModel`, the focal length held by the prior); the mapper keeps
the tracked pixels as the lens saw them and, after each such adjustment, their undistorted positions for
the pinhole steps (PnP, triangulation, outlier tests).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from workers.common.jobctx import JobInputError

from . import bundle
from .calibration import Intrinsics
from .camera_models import PinholeModel, RadialModel, pose_params, poses_from_params
from .frames import SelectionStats, Skipped, open_media, select_frames
from .localise import MIN_INLIERS, Located, SideView, follow_skipped, locate
from .multiview import register_pnp, select_keyframes, triangulate_pairs, two_view
from .params import ReconstructionParams
from .selfcal import DISTORTION_PRIOR_SIGMA, FocalPrior, distort_pixels, undistort_pixels
from .tracks import FlowTracker, SiftTracker, TrackSet

ProgressFn = Callable[[float, str], None]

_MIN_TRACKS = 20
_MIN_INIT_POINTS = 30
_MIN_PNP = MIN_INLIERS
_LOCAL_WINDOW = 8
_LOCAL_ITERATIONS = 8
_INIT_FIRST = 6     # initial pairs are searched among the first keyframes ...
_INIT_SPAN = 6      # ... and this many keyframes after each
_SELFCAL_MIN_FRAMES = 4  # the lens is refined once this many frames are posed (two views say little about it)
# The images refine the focal length unless what they alone say lies farther than this many combined
# standard deviations from the prior: a conflict. Along a direction they barely see (a flat scene from
# above: f, altitude and distortion trade off exactly) their pull is model error (sfm/drone_fc350: 6.5
# sigmas, towards 580 px against the EXIF 702 px), and the prior holds the focal length.
_FOCAL_CONFLICT = 3.0
CENTRE_PRIOR_SIGMA = 0.01
"""Standard deviation of the principal point's prior (at the image centre), as a fraction of the image's larger
side. A flight whose lines turn the camera by 180 degrees sees a principal point's offset as a sideways shift of
every line, alternating with the heading (sfm/drone_fc350: camera centres 0.97 m to the side of their GPS, relative
to the heading, with the principal point at the centre; 0.16 m with it found 7.6 px to the left), so the images
determine it there; along one straight line it trades with the camera's tilt, and the prior holds it. (The larger
side is taken as twice the larger coordinate of the image centre the principal point starts from.)"""


@dataclass
class Lens:
    """The self-calibrated camera at the working resolution: focal length ``f`` (pixels), radial
    distortion ``k1``, ``k2`` (OpenCV's, of the normalised image point), principal point ``centre``
    (2,) pixels (from ``centre_start``, the image centre, refined under a weak prior);
    ``prior`` where the focal length started and how firmly it is held; ``adjustments`` counts the bundle
    adjustments that refined it."""

    f: float
    k1: float
    k2: float
    centre: np.ndarray
    prior: FocalPrior
    centre_start: np.ndarray = field(default=None)  # type: ignore[assignment]
    adjustments: int = 0
    focal_data_sigma: float | None = None
    """The focal length's standard deviation (pixels) that the images alone gave at the last refinement."""
    focal_conflict: float | None = None
    """How far (combined standard deviations) what the images alone say lay from the prior, last time."""
    focal_refined: bool = False
    """Whether the last refinement let the images move the focal length (else it stayed at the prior)."""
    fixed: bool = False
    """Held as it is: calibrated elsewhere (a large survey's reference submodel), never refined here."""

    def __post_init__(self) -> None:
        self.centre = np.asarray(self.centre, np.float64).copy()
        if self.centre_start is None:
            self.centre_start = self.centre.copy()

    @property
    def K(self) -> np.ndarray:
        """The pinhole matrix (3, 3) of the undistorted image."""
        return np.array([[self.f, 0.0, self.centre[0]], [0.0, self.f, self.centre[1]], [0.0, 0.0, 1.0]])

    def intrinsics(self) -> Intrinsics:
        """As :class:`Intrinsics` (OpenCV distortion ``k1 k2 0 0``, None when both are zero)."""
        dist = None if self.k1 == 0.0 and self.k2 == 0.0 else np.array([self.k1, self.k2, 0.0, 0.0])
        return Intrinsics(self.f, self.f, float(self.centre[0]), float(self.centre[1]), dist)

    def undistort(self, xy: np.ndarray) -> np.ndarray:
        """The lens's pixels (N, 2) -> the undistorted image's (N, 2) float64."""
        return undistort_pixels(xy, self.f, self.k1, self.k2, self.centre)

    def distort(self, xy: np.ndarray) -> np.ndarray:
        """The undistorted image's pixels (N, 2) -> the lens's (N, 2) float64."""
        return distort_pixels(xy, self.f, self.k1, self.k2, self.centre)


@dataclass
class SparseModel:
    """The result. Poses and pixels refer to the working resolution (``scale`` x native).

    K (3, 3); frames: ``frame_index`` (F,) decoded-frame numbers, ``frame_time`` (seconds or
    None), ``frame_name``; ``keyframe``/``registered`` (F,) bool; R (F, 3, 3), t (F, 3)
    world-to-camera (identity/zero where unregistered); points (P, 3), colors (P, 3) uint8 BGR,
    point_error (P,) mean reprojection error in pixels; BA observations obs_frame (M,),
    obs_point (M,), obs_xy (M, 2) pixels; ``report`` a JSON-able summary.
    ``frame_registration`` (F,) 'map' (posed by the incremental mapping and bundle adjustment),
    'pnp' (registered afterwards by PnP against the map; with ``joint_ba`` then refined with it) or None; ``frame_inliers`` (F,) int64
    observations in the final map ('map') or PnP inliers ('pnp'); ``frame_failure`` why an
    unregistered frame has no pose. ``skipped``: the decoded frames selection left out, each
    with its pose against the map or the reason it has none. ``obs_xy`` are pixels of the undistorted
    image (``K``); with self-calibration ``intrinsics.dist`` holds the lens's distortion (``lens`` the
    refined camera), and the frames must be undistorted with it to match ``K``.
    """

    K: np.ndarray
    intrinsics: Intrinsics
    scale: float
    width: int
    height: int
    frame_index: np.ndarray
    frame_time: list[float | None]
    frame_name: list[str]
    keyframe: np.ndarray
    registered: np.ndarray
    R: np.ndarray
    t: np.ndarray
    points: np.ndarray
    colors: np.ndarray
    point_error: np.ndarray
    obs_frame: np.ndarray
    obs_point: np.ndarray
    obs_xy: np.ndarray
    report: dict[str, Any] = field(default_factory=dict)
    frame_registration: list[str | None] = field(default_factory=list)
    frame_inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    frame_failure: list[str | None] = field(default_factory=list)
    skipped: list[tuple[SideView, Located]] = field(default_factory=list)
    lens: Lens | None = None
    world: str | None = None
    """The world frame in words once the model was moved into one (:mod:`workers.drone.georef`); None: the
    reconstruction's own frame."""

    def points_by_frame(self) -> list[np.ndarray]:
        """Per frame (F entries), the indices (int64) into ``points`` of its observations, in their order."""
        order = np.argsort(self.obs_frame, kind="stable")
        bounds = np.searchsorted(self.obs_frame[order], np.arange(len(self.registered) + 1))
        return [self.obs_point[order[bounds[f]:bounds[f + 1]]] for f in range(len(self.registered))]


def _stage(progress: ProgressFn | None, fraction: float, stage: str) -> None:
    if progress is not None:
        progress(fraction, stage)


# ---------------------------------------------------------------------------------------------
# Frames and tracks
# ---------------------------------------------------------------------------------------------
@dataclass
class Tracked:
    """What the mapping starts from: the tracks over the selected frames, what selection did, each frame's
    decoded-frame number, time (s, None for stills) and name, the seconds spent decoding and tracking,
    decoding errors, and the frames selection left out (followed into by optical flow)."""

    tracks: TrackSet
    stats: SelectionStats
    index: list[int]
    time: list[float | None]
    name: list[str]
    seconds_decode: float
    seconds_track: float
    errors: list[str]
    side: list[SideView] = field(default_factory=list)


def track_media(media: str | Path, intrinsics: Intrinsics, p: ReconstructionParams,
                progress: ProgressFn | None = None, span: float = 0.55, media_name: str | None = None) -> Tracked:
    """Decode, select and track frames of ``media`` (progress from 0 to ``span``); ``media_name``
    names it in messages (see :func:`open_media`)."""
    source = open_media(media, media_name)
    stats = SelectionStats()
    K = None
    tracker = None
    idx: list[int] = []
    times: list[float | None] = []
    names: list[str] = []
    t_track = 0.0
    t0 = time.perf_counter()
    stage = ["decode"]
    side: list[SideView] = []

    def on_skipped(skipped: Skipped) -> None:
        # Called before the next selected frame: the tracker's last frame is the one before it.
        side.append(follow_skipped(skipped, tracker.last_frame() if tracker is not None else None, len(idx) - 1,
                                   p.fb_threshold, p.lk_window, p.lk_levels))

    def on_decoded(n: int) -> None:
        if source.count:
            _stage(progress, span * min(n / source.count, 1.0), stage[0])

    for frame in select_frames(source, intrinsics, p.frame_step, p.min_motion, p.blur_ratio, p.max_frames,
                               p.max_width, stats, on_decoded, on_skipped):
        if tracker is None:
            K = intrinsics.scaled(stats.scale).K
            tracker = (FlowTracker if p.matcher == "fast_lk" else SiftTracker)(K, p)
        t1 = time.perf_counter()
        tracker.add(frame)
        t_track += time.perf_counter() - t1
        idx.append(frame.index)
        times.append(frame.time)
        names.append(frame.name)
        expected = _expected_frames(source.count, stats)
        done = min(stats.decoded / source.count, 1.0) if source.count else 0.0
        stage[0] = f"track {len(idx)}/{expected}" if expected else f"track {len(idx)}"
        _stage(progress, span * done, stage[0])
    if stats.decoded == 0:
        raise JobInputError(f"{source.name}: no decodable frames"
                            + (f" ({source.errors[0]})" if source.errors else ""))
    if len(idx) < 2:
        raise JobInputError(f"{source.name}: only {len(idx)} usable frame(s) of {stats.decoded} decoded; "
                            "a reconstruction needs at least two")
    tracks = tracker.result()
    return Tracked(tracks, stats, idx, times, names, time.perf_counter() - t0 - t_track, t_track, source.errors,
                    side)


def _expected_frames(count: int | None, stats: SelectionStats) -> int | None:
    if not count or stats.decoded == 0:
        return None
    return max(stats.selected, int(round(stats.selected * count / stats.decoded)))


# ---------------------------------------------------------------------------------------------
# Incremental mapping
# ---------------------------------------------------------------------------------------------
class _Mapper:
    """State of the incremental reconstruction over the keyframes' observations."""

    def __init__(self, tracks: TrackSet, keyframes: np.ndarray, K: np.ndarray, p: ReconstructionParams,
                 lens: Lens | None = None) -> None:
        self.tracks = tracks
        self.K = K
        self.p = p
        self.lens = lens
        # Tracked pixels as the lens saw them (raw) and undistorted for the current lens (pinhole steps).
        self.track_xy = tracks.obs_xy.copy()
        n_frames = tracks.n_frames
        self.is_key = np.zeros(n_frames, bool)
        self.is_key[keyframes] = True
        sel = self.is_key[tracks.obs_frame]
        self.of = tracks.obs_frame[sel]
        self.ot = tracks.obs_track[sel]
        self.xy_raw = tracks.obs_xy[sel]
        self.xy = self.undistort(self.xy_raw)
        if lens is not None:  # a lens calibrated elsewhere: its pinhole and undistorted pixels from the start
            self.K = lens.K
            self.track_xy = lens.undistort(tracks.obs_xy)
        self.rgb = tracks.obs_rgb[sel]
        self.valid = np.ones(len(self.of), bool)
        self.by_track = np.argsort(self.ot, kind="stable")
        self.track_start = np.concatenate([[0], np.cumsum(np.bincount(self.ot, minlength=tracks.n_tracks))])
        self.track_point = np.full(tracks.n_tracks, -1, np.int64)
        self.X = np.zeros((0, 3))
        self.X0 = np.zeros((0, 3))  # initial values (DLT / PnP), kept for the report
        self.point_track = np.zeros(0, np.int64)
        self.alive = np.zeros(0, bool)
        self.reg = np.zeros(n_frames, bool)
        self.R = np.tile(np.eye(3), (n_frames, 1, 1))
        self.t = np.zeros((n_frames, 3))
        self.R0 = self.R.copy()
        self.t0 = self.t.copy()
        self.order: list[int] = []
        self.gauge = -1
        self.fail_count = np.zeros(n_frames, np.int64)

    def rows(self, f: int) -> np.ndarray:
        lo, hi = np.searchsorted(self.of, [f, f + 1])
        return np.arange(lo, hi)

    def _add_points(self, track_ids: np.ndarray, X: np.ndarray) -> None:
        start = len(self.X)
        self.X = np.vstack([self.X, X])
        self.X0 = np.vstack([self.X0, X])
        self.point_track = np.concatenate([self.point_track, track_ids])
        self.alive = np.concatenate([self.alive, np.ones(len(X), bool)])
        self.track_point[track_ids] = np.arange(start, start + len(X))

    def _set_pose(self, f: int, R: np.ndarray, t: np.ndarray) -> None:
        self.R[f], self.t[f] = R, t
        self.R0[f], self.t0[f] = R, t
        self.reg[f] = True
        self.order.append(f)

    # -- the initial pair (III-C) -------------------------------------------------------------
    def initialise(self, keyframes: np.ndarray) -> tuple[int, int]:
        """Find the first keyframe pair with enough parallax; raises JobInputError when none."""
        p = self.p
        best_angle = 0.0
        for i, k0 in enumerate(keyframes[:_INIT_FIRST]):
            r0 = self.rows(int(k0))
            for k1 in keyframes[i + 1:i + 1 + _INIT_SPAN]:
                r1 = self.rows(int(k1))
                common, ia, ib = np.intersect1d(self.ot[r0], self.ot[r1], assume_unique=True, return_indices=True)
                if len(common) < _MIN_INIT_POINTS:
                    continue
                tv = two_view(self.xy[r0[ia]], self.xy[r1[ib]], self.K, p.ransac_threshold,
                              p.reprojection_threshold, p.min_triangulation_angle)
                if tv is None:
                    continue
                best_angle = max(best_angle, tv.median_angle)
                if tv.good.sum() >= _MIN_INIT_POINTS and tv.median_angle >= p.min_triangulation_angle:
                    self._set_pose(int(k0), np.eye(3), np.zeros(3))
                    self._set_pose(int(k1), tv.R, tv.t)
                    self.gauge = int(k0)
                    self._add_points(common[tv.good], tv.X[tv.good])
                    return int(k0), int(k1)
        raise JobInputError(
            "the camera does not move enough to see depth: no pair of frames gives a triangulation angle of "
            f"{p.min_triangulation_angle:g} degrees (best {best_angle:.2f}); a hovering or only-rotating camera "
            "cannot be reconstructed")

    # -- registration and triangulation -------------------------------------------------------
    def _observed_points(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pt = self.track_point[self.ot[rows]]
        keep = self.valid[rows] & (pt >= 0)
        return rows[keep], pt[keep]

    def register_next(self) -> int | None:
        """Register the unregistered keyframe that sees most points; None when none can be."""
        cand = self.is_key & ~self.reg
        use = self.valid & cand[self.of] & (self.track_point[self.ot] >= 0)
        counts = np.bincount(self.of[use], minlength=len(self.reg))
        counts[counts <= 1.5 * self.fail_count] = 0
        while True:
            f = int(np.argmax(counts))
            if counts[f] < _MIN_PNP:
                return None
            rows, pt = self._observed_points(self.rows(f))
            res = register_pnp(self.X[pt], self.xy[rows], self.K, self.p.reprojection_threshold, _MIN_PNP)
            if res is None:
                self.fail_count[f] = counts[f]
                counts[f] = 0
                continue
            R, t, inl = res
            self.valid[rows[~inl]] = False
            self._set_pose(f, R, t)
            return f

    def triangulate(self, f: int) -> int:
        """New points for tracks seen in frame f and in another registered keyframe."""
        rows = self.rows(f)
        rows = rows[self.valid[rows] & (self.track_point[self.ot[rows]] < 0)]
        if len(rows) == 0:
            return 0
        tids = self.ot[rows]
        starts = self.track_start[tids]
        lens = self.track_start[tids + 1] - starts
        owner = np.repeat(np.arange(len(tids)), lens)
        pos = np.arange(int(lens.sum())) - np.repeat(np.cumsum(lens) - lens, lens) + np.repeat(starts, lens)
        other = self.by_track[pos]
        ok = self.valid[other] & self.reg[self.of[other]] & (self.of[other] != f)
        owner, other = owner[ok], other[ok]
        if len(owner) == 0:
            return 0
        # The partner farthest along the sequence gives the widest baseline.
        order = np.lexsort((-np.abs(self.of[other] - f), owner))
        owner, other = owner[order], other[order]
        first = np.unique(owner, return_index=True)[1]
        owner, other = owner[first], other[first]
        fo = self.of[other]
        X, good = triangulate_pairs(self.K, self.R[f], self.t[f], self.xy[rows[owner]], self.R[fo], self.t[fo],
                                    self.xy[other], self.p.reprojection_threshold, self.p.min_triangulation_angle)
        self._add_points(tids[owner[good]], X[good])
        return int(good.sum())

    def add_frames(self, frames: np.ndarray) -> None:
        """Bring the observations of ``frames`` (non-keyframes registered by PnP) into the map, so
        that the next bundle adjustment refines their poses with it and their tracks constrain the
        points (only the observations of tracks with a map point)."""
        t = self.tracks
        new = np.isin(t.obs_frame, frames) & ~self.is_key[t.obs_frame]
        pt = self.track_point[t.obs_track[new]]
        new[np.flatnonzero(new)[pt < 0]] = False
        if not new.any():
            return
        self.is_key[frames] = True
        of = np.concatenate([self.of, t.obs_frame[new]])
        order = np.argsort(of, kind="stable")
        self.of = of[order]
        self.ot = np.concatenate([self.ot, t.obs_track[new]])[order]
        self.xy = np.concatenate([self.xy, self.track_xy[new]])[order]
        self.xy_raw = np.concatenate([self.xy_raw, t.obs_xy[new]])[order]
        self.rgb = np.concatenate([self.rgb, t.obs_rgb[new]])[order]
        self.valid = np.concatenate([self.valid, np.ones(int(new.sum()), bool)])[order]
        self.by_track = np.argsort(self.ot, kind="stable")
        self.track_start = np.concatenate([[0], np.cumsum(np.bincount(self.ot, minlength=t.n_tracks))])

    # -- bundle adjustment --------------------------------------------------------------------
    def _ba_rows(self) -> tuple[np.ndarray, np.ndarray]:
        pt = self.track_point[self.ot]
        use = self.valid & self.reg[self.of] & (pt >= 0)
        use[use] = self.alive[pt[use]]
        return np.flatnonzero(use), pt

    def adjust(self, free_frames: np.ndarray | None, iterations: int,
               callback: Callable[[int, float], None] | None = None) -> bundle.BAResult | None:
        """Bundle adjustment of the frames in ``free_frames`` (all registered when None) and the
        points they see; other frames seeing those points stay fixed; the gauge frame is fixed.
        A global adjustment (``free_frames`` None) of a self-calibrating mapper with at least
        ``_SELFCAL_MIN_FRAMES`` posed frames also refines the lens."""
        rows, pt = self._ba_rows()
        if free_frames is not None:
            local = np.zeros(len(self.reg), bool)
            local[free_frames] = True
            seen = np.unique(pt[rows[local[self.of[rows]]]])
            rows = rows[np.isin(pt[rows], seen)]
        if len(rows) == 0:
            return None
        cams, ci = np.unique(self.of[rows], return_inverse=True)
        pts, pj = np.unique(pt[rows], return_inverse=True)
        fixed = np.zeros((len(cams), 6), bool)
        if free_frames is not None:
            fixed[~np.isin(cams, free_frames)] = True
        if not fixed.any():
            fixed[cams == self.gauge] = True
            if not fixed.any():
                fixed[0] = True
        if fixed.all():
            return None
        options = bundle.BAOptions(max_iterations=iterations, loss=self.p.ba_loss, loss_scale=self.p.ba_loss_scale)
        start = pose_params(self.R[cams], self.t[cams])
        if (self.lens is not None and not self.lens.fixed and free_frames is None
                and len(cams) >= _SELFCAL_MIN_FRAMES):
            res = self._adjust_lens(start, pts, ci, pj, self.xy_raw[rows], fixed, options, callback)
        else:
            res = bundle.solve(PinholeModel(self.K, len(cams)), start, self.X[pts], ci, pj, self.xy[rows], fixed,
                               options, callback)
        R, t = poses_from_params(res.params)
        self.R[cams], self.t[cams] = R, t
        self.X[pts] = res.points
        return res

    def _adjust_lens(self, start: np.ndarray, pts: np.ndarray, ci: np.ndarray, pj: np.ndarray, raw: np.ndarray,
                     fixed: np.ndarray, options: bundle.BAOptions, callback) -> bundle.BAResult:
        """Bundle adjustment that also refines the lens (f under its prior, k1, k2 under weak zero-mean
        priors); when the images alone would put f in conflict with the prior (``_FOCAL_CONFLICT``), again
        with f held at the prior. Updates the lens; returns the solver's result."""
        lens = self.lens
        model = RadialModel(lens.centre, refine_centre=True)
        f0 = lens.prior.focal_px
        sigma_f = lens.prior.sigma * f0
        sigma_c = CENTRE_PRIOR_SIGMA * 2.0 * float(max(lens.centre_start))
        prior = bundle.SharedPrior(np.array([f0, 0.0, 0.0, *lens.centre_start]),
                                   np.array([sigma_f, DISTORTION_PRIOR_SIGMA, DISTORTION_PRIOR_SIGMA, sigma_c, sigma_c]))
        res = bundle.solve(model, start, self.X[pts], ci, pj, raw, fixed, options, callback,
                           shared=np.array([lens.f, lens.k1, lens.k2, *lens.centre]), shared_prior=prior)
        info = bundle.shared_information(model, res.params, res.points, res.shared, ci, pj, raw, fixed, options)
        sd = _marginal_sigma(info, 0)
        f = float(res.shared[0])
        # The posterior mean is the precision-weighted mean of prior and data: solve it for the data's own.
        f_images = f + (f - f0) * sd**2 / sigma_f**2 if np.isfinite(sd) else f0
        lens.focal_data_sigma = sd
        lens.focal_conflict = abs(f_images - f0) / float(np.hypot(sd, sigma_f)) if np.isfinite(sd) else 0.0
        lens.focal_refined = bool(lens.focal_conflict <= _FOCAL_CONFLICT)
        if not lens.focal_refined:
            # Back to the prior's focal length along the flat-scene family (s f, s^2 k1, s^4 k2), then held there.
            s = f0 / f
            res = bundle.solve(model, res.params, res.points, ci, pj, raw, fixed, options, callback,
                               shared=np.array([f0, res.shared[1] * s**2, res.shared[2] * s**4, *res.shared[3:]]),
                               shared_fixed=np.array([True, False, False, False, False]), shared_prior=prior)
        self._set_lens(*res.shared)
        return res

    def _set_lens(self, f: float, k1: float, k2: float, cx: float, cy: float) -> None:
        """Adopt a refined lens: K and the undistorted pixels follow it."""
        lens = self.lens
        lens.f, lens.k1, lens.k2 = float(f), float(k1), float(k2)
        lens.centre = np.array([cx, cy], np.float64)
        lens.adjustments += 1
        self.K = lens.K
        self.xy = lens.undistort(self.xy_raw)
        self.track_xy = lens.undistort(self.tracks.obs_xy)

    def undistort(self, xy: np.ndarray) -> np.ndarray:
        """Pixels as the lens saw them (N, 2) -> the undistorted image's, for the pinhole steps."""
        return self.lens.undistort(xy) if self.lens is not None else np.asarray(xy, np.float64)

    def errors(self, initial: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Rows used by BA and their reprojection errors (pixels; inf behind the camera), with
        the current values or (``initial``) the values first estimated by DLT and PnP/E."""
        rows, pt = self._ba_rows()
        f = self.of[rows]
        R, t, X = (self.R0, self.t0, self.X0) if initial else (self.R, self.t, self.X)
        P = np.einsum("nij,nj->ni", R[f], X[pt[rows]]) + t[f]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = P[:, :2] / P[:, 2:3] @ self.K[:2, :2].T + self.K[:2, 2]
            err = np.linalg.norm(uv - self.xy[rows], axis=1)
        err[~(P[:, 2] > 0)] = np.inf
        return rows, err

    def filter_outliers(self) -> int:
        """Drop observations above the reprojection threshold, then points seen fewer than twice."""
        rows, err = self.errors()
        bad = rows[~(err <= self.p.reprojection_threshold)]
        self.valid[bad] = False
        rows, pt = self._ba_rows()
        counts = np.bincount(pt[rows], minlength=len(self.X))
        dead = self.alive & (counts < 2)
        self.alive[dead] = False
        self.track_point[self.point_track[dead]] = -1
        return len(bad)


# ---------------------------------------------------------------------------------------------
# The pipeline
# ---------------------------------------------------------------------------------------------
def reconstruct(media: str | Path, intrinsics: Intrinsics, params: ReconstructionParams,
                progress: ProgressFn | None = None, media_name: str | None = None,
                focal_prior: FocalPrior | None = None) -> SparseModel:
    """Reconstruct cameras and a sparse point cloud from a video or ordered stills.

    ``intrinsics`` refer to the media's native resolution. With ``focal_prior`` (native resolution)
    they are only the start of self-calibration (no distortion): the global bundle adjustments refine
    the focal length (held by the prior) and radial distortion shared by every frame. ``progress(fraction, stage)`` reports
    stages 'decode', 'track k/N', 'keyframes', 'initialise', 'register k/N', 'BA iteration i'
    and 'localise' (the final joint adjustment included) with fractions up to 0.97 (the caller writes the outputs and reports 'done').
    User-caused failures raise JobInputError; ``media_name`` names the media in their messages.
    """
    tr = track_media(media, intrinsics, params, progress, media_name=media_name)
    return map_tracks(tr, intrinsics, params, progress, focal_prior)


def map_tracks(tr: Tracked, intrinsics: Intrinsics, params: ReconstructionParams, progress: ProgressFn | None = None,
               focal_prior: FocalPrior | None = None, lens: Lens | None = None,
               all_keyframes: bool = False) -> SparseModel:
    """The mapping half of :func:`reconstruct`: keyframes, the initial pair, registration, bundle adjustment and
    the frames outside the map, from tracks already made (``tr``; progress from 0.56 to 0.97).

    ``focal_prior``: self-calibrate starting there (see :func:`reconstruct`); ``lens``: instead, a lens calibrated
    elsewhere (``fixed``), held as it is while the tracked pixels (as that lens saw them) are undistorted with it;
    neither: ``intrinsics`` as they are (the tracked frames were undistorted with them). ``all_keyframes``: every
    frame is a keyframe (stills whose tracks do not follow the frame order, as a survey's cross-line matches)."""
    p = params
    timings: dict[str, float] = {"decode": tr.seconds_decode, "track": tr.seconds_track}
    tracks, stats = tr.tracks, tr.stats
    if tracks.n_tracks < _MIN_TRACKS:
        raise JobInputError(f"only {tracks.n_tracks} features could be followed across frames; the video may be "
                            "blank, too dark, or out of focus")
    intr = intrinsics.scaled(stats.scale)
    K = intr.K
    width = stats.working_size[0]
    if focal_prior is not None:
        lens = Lens(intr.fx, 0.0, 0.0, np.array([intr.cx, intr.cy]), focal_prior.scaled(stats.scale))

    t0 = time.perf_counter()
    _stage(progress, 0.56, "keyframes")
    # SIFT tracks need not follow the frame order; its frames are all keyframes.
    keyframes = (select_keyframes(tracks, width, p.keyframe_parallax) if p.matcher == "fast_lk" and not all_keyframes
                 else np.arange(tracks.n_frames))
    if len(keyframes) < 2:
        raise JobInputError("the camera never moves: tracked features shifted less than "
                            f"{p.keyframe_parallax:.1%} of the image width over the whole input (no parallax)")
    mapper = _Mapper(tracks, keyframes, K, p, lens)
    _stage(progress, 0.58, "initialise")
    mapper.initialise(keyframes)
    mapper.adjust(None, 20)
    timings["initialise"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    last_global = len(mapper.order)
    n_key = len(keyframes)
    while True:
        f = mapper.register_next()
        if f is None:
            break
        mapper.triangulate(f)
        if len(mapper.order) >= 1.3 * last_global + 2:
            mapper.adjust(None, 15)
            mapper.filter_outliers()
            last_global = len(mapper.order)
        else:
            mapper.adjust(np.asarray(mapper.order[-_LOCAL_WINDOW:]), _LOCAL_ITERATIONS)
        _stage(progress, 0.6 + 0.2 * len(mapper.order) / n_key, f"register {len(mapper.order)}/{n_key}")
    timings["register"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    mapper.filter_outliers()
    rounds = 0

    def ba_progress(i: int, cost: float) -> None:
        # Up to four rounds share 0.80..0.95; the iteration count restarts each round.
        _stage(progress, 0.8 + 0.15 * (rounds - 1 + min(i / p.ba_iterations, 1.0)) / 4, f"BA iteration {i}")

    final = None
    for rounds in range(1, 4):
        final = mapper.adjust(None, p.ba_iterations, ba_progress) or final
        if mapper.filter_outliers() == 0:
            break
    else:
        rounds = 4
        final = mapper.adjust(None, p.ba_iterations, ba_progress) or final
    timings["bundle_adjustment"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    _stage(progress, 0.95, "localise")
    mapped = mapper.reg.copy()
    located = _localise_rest(mapper, tracks)
    timings["localise"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if p.joint_ba:
        final = _adjust_with_located(mapper, np.flatnonzero(mapper.reg & ~mapped), p.ba_iterations) or final
    timings["joint_adjustment"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    skipped = [(v, _locate_side(mapper, tracks, v)) for v in tr.side]
    timings["localise"] += time.perf_counter() - t0
    _, err0 = mapper.errors(initial=True)
    _, err1 = mapper.errors()
    _stage(progress, 0.97, "localise")

    model = _assemble(mapper, tracks, lens.intrinsics() if lens is not None else intr, stats, tr, keyframes)
    model.lens = lens
    rows, _ = mapper.errors()
    model.frame_registration = ["map" if mapped[f] else "pnp" if mapper.reg[f] else None
                                for f in range(tracks.n_frames)]
    model.frame_inliers = np.bincount(mapper.of[rows], minlength=tracks.n_frames).astype(np.int64)
    model.frame_failure = [None] * tracks.n_frames
    for f, loc in located.items():
        model.frame_inliers[f] = loc.inliers
        model.frame_failure[f] = loc.failure
    model.skipped = skipped
    model.report = _report(model, tr, p, keyframes, mapper, len([v for v in located.values() if v.R is not None]),
                           err0, err1, final, rounds, timings)
    return model


def _marginal_sigma(information: np.ndarray, i: int) -> float:
    """Standard deviation of parameter ``i`` from an information matrix (g, g); inf where singular."""
    try:
        var = float(np.linalg.inv(information)[i, i])
    except np.linalg.LinAlgError:
        return float("inf")
    return float(np.sqrt(var)) if var > 0 and np.isfinite(var) else float("inf")


def _map_points(mapper: _Mapper, track_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices (K,) into ``track_ids`` of tracks with a live map point, and those points (K,)."""
    pt = np.where(track_ids >= 0, mapper.track_point[np.maximum(track_ids, 0)], -1)
    ok = pt >= 0
    ok[ok] = mapper.alive[pt[ok]]
    return np.flatnonzero(ok), pt[ok]


def _localise_rest(mapper: _Mapper, tracks: TrackSet) -> dict[int, Located]:
    """PnP for every selected frame not registered yet, against the final points (no map changes)."""
    out = {}
    for f in np.flatnonzero(~mapper.reg):
        sl = tracks.frame_slice(int(f))
        rows, pt = _map_points(mapper, tracks.obs_track[sl])
        loc = locate(mapper.X[pt], mapper.track_xy[sl][rows], mapper.K, mapper.p.reprojection_threshold, _MIN_PNP)
        if loc.R is not None:
            mapper.R[f], mapper.t[f] = loc.R, loc.t
            mapper.R0[f], mapper.t0[f] = loc.R, loc.t
            mapper.reg[f] = True
        out[int(f)] = loc
    return out


def _adjust_with_located(mapper: _Mapper, frames: np.ndarray, iterations: int) -> bundle.BAResult | None:
    """The final bundle adjustment (eq. 5) over the keyframes and the selected ``frames`` (F,)
    registered by PnP: their tracked observations join the map's, all poses and points are refined
    together, outliers above the reprojection threshold are removed between rounds (at most three).
    Returns the last solver result; None when ``frames`` is empty or no adjustment ran."""
    if len(frames) == 0:
        return None
    mapper.add_frames(frames)
    res = None
    for _ in range(3):
        res = mapper.adjust(None, iterations) or res
        if mapper.filter_outliers() == 0:
            break
    return res


def _locate_side(mapper: _Mapper, tracks: TrackSet, view: SideView) -> Located:
    """Pose of a frame selection left out, from the features followed into it (no map changes)."""
    if view.failure is not None:
        return Located(None, None, 0, 0, view.failure)
    raw = tracks.raw_to_track
    known = view.keys < len(raw)
    tid = np.full(len(view.keys), -1, np.int64)
    tid[known] = raw[view.keys[known]]
    rows, pt = _map_points(mapper, tid)
    return locate(mapper.X[pt], mapper.undistort(view.xy[rows]), mapper.K, mapper.p.reprojection_threshold, _MIN_PNP)


def _assemble(mapper: _Mapper, tracks: TrackSet, intr: Intrinsics, stats: SelectionStats, tr: Tracked,
              keyframes: np.ndarray) -> SparseModel:
    rows, err = mapper.errors()
    pt = mapper.track_point[mapper.ot[rows]]
    used, new_id = np.unique(pt, return_inverse=True)
    counts = np.bincount(new_id, minlength=len(used)).astype(np.float64)
    colors = np.stack([np.bincount(new_id, mapper.rgb[rows, c].astype(np.float64), len(used)) for c in range(3)], 1)
    colors = np.clip(np.rint(colors / counts[:, None]), 0, 255).astype(np.uint8)
    point_error = np.bincount(new_id, err, len(used)) / counts
    key = np.zeros(tracks.n_frames, bool)
    key[keyframes] = True
    return SparseModel(
        K=intr.K, intrinsics=intr, scale=stats.scale, width=stats.working_size[0], height=stats.working_size[1],
        frame_index=np.asarray(tr.index), frame_time=tr.time, frame_name=tr.name, keyframe=key,
        registered=mapper.reg.copy(), R=mapper.R.copy(), t=mapper.t.copy(), points=mapper.X[used].copy(),
        colors=colors, point_error=point_error, obs_frame=mapper.of[rows].copy(), obs_point=new_id,
        obs_xy=mapper.xy[rows].copy())


def _summary(err: np.ndarray) -> dict[str, float | None]:
    e = err[np.isfinite(err)]
    if len(e) == 0:
        return {"mean": None, "median": None}
    return {"mean": float(e.mean()), "median": float(np.median(e))}


def _report(model: SparseModel, tr: Tracked, p: ReconstructionParams, keyframes: np.ndarray, mapper: _Mapper,
            localised: int, err0: np.ndarray, err1: np.ndarray, final: bundle.BAResult | None, rounds: int,
            timings: dict[str, float]) -> dict[str, Any]:
    pairs = tr.tracks.pairs
    proposed = sum(s.proposed for s in pairs)
    stats = tr.stats
    matcher: dict[str, Any] = {
        "name": p.matcher,
        "pairs": len(pairs),
        "inlier_ratio_mean": float(np.mean([s.inlier_ratio for s in pairs])) if pairs else None,
        "proposed": proposed,
        "inliers": sum(s.inliers for s in pairs),
    }
    if p.matcher == "fast_lk" and proposed:
        matcher["rejected_forward_backward"] = sum(s.proposed - s.after_fb for s in pairs) / proposed
        matcher["rejected_fast_rule"] = sum(s.after_fb - s.after_rule for s in pairs) / proposed
        matcher["rejected_ransac"] = sum(s.after_rule - s.inliers for s in pairs) / proposed
        # Flows only the rule rejected, whose tracks went on (params.max_track_gap).
        matcher["bridged_by_track_gap"] = sum(s.bridged for s in pairs) / proposed
    warnings = list(tr.errors[:20])
    if stats.truncated:
        warnings.append(f"stopped after max_frames={p.max_frames} selected frames; the rest of the video was not used")
    if stats.stride > 1:
        warnings.append(f"max_frames={p.max_frames}: every {stats.stride}th frame of the video was considered for "
                        "tracking (the others are posed afterwards against the map where they can be)")
    return {
        "media": {"native_size": list(stats.native_size), "working_size": list(stats.working_size),
                  "scale": stats.scale},
        "frames": {"decoded": stats.decoded, "selected": stats.selected, "skipped_blurred": stats.skipped_blurred,
                   "stride": stats.stride, "keyframes": int(len(keyframes)),
                   "keyframes_registered": int((model.registered & model.keyframe).sum()),
                   "registered": int(model.registered.sum()), "localised_by_pnp": localised,
                   "skipped_by_selection": len(model.skipped),
                   "skipped_registered": sum(loc.R is not None for _, loc in model.skipped)},
        "tracks": {"count": tr.tracks.n_tracks, "observations": int(len(tr.tracks.obs_frame)),
                   "mean_length": float(len(tr.tracks.obs_frame) / max(tr.tracks.n_tracks, 1))},
        "matcher": matcher,
        "points": int(len(model.points)),
        "observations_in_ba": int(len(model.obs_frame)),
        # before: the initial values (DLT points, poses from E / PnP); after: the final model
        "reprojection_error_px": {"before_ba": _summary(err0), "after_ba": _summary(err1)},
        "bundle_adjustment": {
            "rounds": rounds, "loss": p.ba_loss,
            "final_cost": final.final_cost if final else None,
            "iterations_last_round": final.iterations if final else None,
            "termination": final.termination if final else None,
        },
        "intrinsics": _intrinsics_report(model, mapper.lens),
        "timings_s": {k: round(v, 4) for k, v in timings.items()},
        "warnings": warnings,
    }


def _intrinsics_report(model: SparseModel, lens: Lens | None) -> dict[str, Any]:
    """Which intrinsics were used and, when self-calibrated, what was found (native-resolution pixels)."""
    native = model.intrinsics.scaled(1.0 / model.scale)
    out: dict[str, Any] = {"fx": native.fx, "fy": native.fy, "cx": native.cx, "cy": native.cy,
                           "distortion": None if native.dist is None else [float(v) for v in native.dist]}
    if lens is None:
        return {"source": "given", "self_calibrated": False, **out}
    start = lens.prior.focal_px / model.scale
    return {"source": lens.prior.source, "detail": lens.prior.detail, "self_calibrated": lens.adjustments > 0,
            "model": "RADIAL (f, k1, k2, principal point cx, cy)", **out,
            "principal_point_start_px": [float(v) / model.scale for v in lens.centre_start],
            "focal_start_px": start, "focal_change": native.fx / start - 1.0,
            "focal_prior_sigma_px": lens.prior.sigma * start,
            "focal_images_sigma_px": None if lens.focal_data_sigma is None else lens.focal_data_sigma / model.scale,
            "focal_conflict_sigmas": lens.focal_conflict, "focal_refined": lens.focal_refined,
            "focal_note": ("refined by the images under the prior" if lens.focal_refined else
                           f"what the images alone say lies {lens.focal_conflict:.1f} sigmas from the prior (more than "
                           f"{_FOCAL_CONFLICT:g}: model error along a direction they barely see, as over a flat scene "
                           "seen from above): held at the prior; distortion refined"),
            "adjustments": lens.adjustments}
