"""The sparse stages of a survey as tasks (:mod:`workers.fanout`), their outputs in the job's work area.

1. :func:`track_block`: a block of consecutive photos (:mod:`.plan`) decoded once, followed by the paper's FAST +
   optical flow with its outlier rule (:class:`~workers.drone.tracks.FlowTracker`), and each photo's SIFT
   features kept for the pairs; also each photo's sharpness (the orthophoto's choice of frame).
2. :func:`match_pairs`: photos of neighbouring flight lines (and the ends of blocks) matched by SIFT
   (``max_features`` a photo; ratio test by FLANN, RANSAC on the essential matrix).
3. :func:`map_submodel`: a submodel's photos, their block tracks and their pairs' matches (joined into tracks
   as connected components, each track then measured by the optical flow from its first photo: SIFT finds the
   correspondences, but its keypoints lie some 0.3 px (rms) from where the flow puts the same ground, and on a nadir
   survey, whose focal length the images barely determine, that was enough to bend the self-calibrated lens by
   1.3 % and lift the map's ground by 1.8 m) mapped as the paper's incremental reconstruction does
   (:func:`workers.drone.reconstruction.map_tracks`, every photo a keyframe), then placed in the survey's UTM
   frame by its GPS (and optionally adjusted with the GPS as a prior).

Each writes its output before it returns, under a name the next attempt looks for: a stage that finished is
never run again (:mod:`.stages`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from workers.common.jobctx import JobInputError
from workers.workarea import WorkArea

from ..calibration import Intrinsics
from ..exif import GeoPoint
from ..features import sift_features
from ..frames import Frame, SelectionStats, sharpness
from ..georef import Georeference, GeoreferenceError, apply, georeference, gps_adjust
from ..matching import PairStats, essential_inliers, sift_ratio_matches_flann
from ..params import ReconstructionParams
from ..reconstruction import Lens, SparseModel, Tracked, map_tracks
from ..selfcal import FocalPrior
from ..tracks import FlowTracker, TrackSet, colours_at, tracks_from_observations
from .photos import PhotoSource, working_image

MIN_PAIR_INLIERS = 15
"""A pair of photos shares its matches only with at least this many consistent with one essential matrix."""
PAIR_RANSAC_PX = 2.0
MATCH_MAX_SIDE = 640
"""Long side (px) at most of the copy SIFT finds the pairs' correspondences in: the optical flow measures every
matched keypoint again at the working resolution (:func:`measure_by_flow`), so SIFT need only find which ground
is which; on the 1200 x 900 fc350 stills its features at full size cost 0.3 s a photo, about 4x this copy's."""
FLOW_REMEASURE_PX = 1.0
"""A matched keypoint the optical flow moves by more than this (px), or whose flow does not come back as near, is
dropped from its track."""
"""Epipolar distance (px) of the pairs' RANSAC: the lens is not calibrated yet, its distortion still in the pixels."""


@dataclass(frozen=True)
class SparseJob:
    """What every sparse task of one job shares: the work area, where the photos are, the parameters, the
    photos' names in flight order, the working resolution and intrinsics there (the lens's start, or the
    given ones: then the photos are undistorted with them before tracking)."""

    work: WorkArea
    photos: PhotoSource
    params: ReconstructionParams
    names: tuple[str, ...]
    native_size: tuple[int, int]
    scale: float
    intrinsics: Intrinsics
    undistort: bool

    @property
    def working(self) -> Intrinsics:
        return self.intrinsics.scaled(self.scale)


def block_name(b: int) -> str:
    return f"tracks/{b:05d}"


def features_name(pos: int) -> str:
    return f"features/{pos:06d}.npz"


def pairs_name(chunk: int) -> str:
    return f"pairs/{chunk:05d}"


@dataclass(frozen=True)
class BlockItem:
    job: SparseJob
    block: int
    photos: tuple[int, ...]


def track_block(item: BlockItem) -> dict[str, Any]:
    """Follow one block's photos (see the module docstring); returns what the job keeps of it: the photos
    tracked, those that could not be (position -> reason), each one's sharpness, the flow's pair counts and the
    seconds spent decoding and tracking."""
    job, work = item.job, item.job.work
    done = block_name(item.block) + ".json"
    if work.exists(done):
        return work.get_json(done)
    p = job.params
    t0 = time.perf_counter()
    names = [job.names[i] for i in item.photos]
    intr = job.working
    raw = job.photos.raw(names)
    seconds_decode = time.perf_counter() - t0
    tracker = FlowTracker(intr.K, p)
    tracked, failed, sharp = [], {}, {}
    t_track = 0.0
    for pos, name in zip(item.photos, names):
        if name not in raw:
            failed[int(pos)] = "could not be decoded"
            continue
        img, pixel_scale = raw[name]
        if img.shape[1::-1] != job.native_size:
            failed[int(pos)] = (f"size {img.shape[1]}x{img.shape[0]} differs from the first photo's "
                                f"{job.native_size[0]}x{job.native_size[1]}")
            continue
        t1 = time.perf_counter()
        image = working_image(img, job.photos.working_size, intr if job.undistort else replace(intr, dist=None))
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        seconds_decode += time.perf_counter() - t1
        t1 = time.perf_counter()
        tracker.add(Frame(int(pos), None, name, image, gray))
        xy, desc = match_features(gray, p.max_features)
        work.put_arrays(features_name(int(pos)), xy=xy, desc=np.clip(np.rint(desc), 0, 255).astype(np.uint8),
                        rgb=colours_at(image, xy))
        t_track += time.perf_counter() - t1
        sharp[int(pos)] = sharpness(gray)
        tracked.append(int(pos))
    ts = tracker.result()
    where = np.asarray(tracked, np.int64)
    work.put_arrays(block_name(item.block) + ".npz", photo=where[ts.obs_frame] if len(where) else ts.obs_frame,
                    track=ts.obs_track, xy=ts.obs_xy, rgb=ts.obs_rgb)
    meta = {"block": item.block, "tracked": tracked, "failed": failed, "sharpness": sharp,
            "flow_pairs": [[int(where[s.frame0]), int(where[s.frame1]), s.proposed, s.after_fb, s.after_rule,
                            s.inliers, s.bridged] for s in ts.pairs],
            "tracks": ts.n_tracks, "seconds_decode": round(seconds_decode, 4), "seconds_track": round(t_track, 4)}
    work.put_json(done, meta)
    return meta


def match_features(gray: np.ndarray, max_features: int) -> tuple[np.ndarray, np.ndarray]:
    """SIFT keypoints (N, 2) float32 in pixels of ``gray`` ((H, W) uint8; pixel centres at integers) and descriptors
    (N, 128) float32, found in a copy whose long side is at most :data:`MATCH_MAX_SIDE` px."""
    s = min(1.0, MATCH_MAX_SIDE / max(gray.shape[:2]))
    if s >= 1.0:
        return sift_features(gray, max_features)
    small = cv2.resize(gray, (round(gray.shape[1] * s), round(gray.shape[0] * s)), interpolation=cv2.INTER_AREA)
    xy, desc = sift_features(small, max_features)
    sx, sy = gray.shape[1] / small.shape[1], gray.shape[0] / small.shape[0]
    return ((xy + 0.5) * np.array([sx, sy], np.float32) - 0.5).astype(np.float32), desc


@dataclass(frozen=True)
class PairsItem:
    job: SparseJob
    chunk: int
    pairs: tuple[tuple[int, int], ...]


def match_pairs(item: PairsItem) -> dict[str, Any]:
    """SIFT matches of a chunk of photo pairs, kept where at least :data:`MIN_PAIR_INLIERS` fit one essential
    matrix; written as (i, j, keypoint in i, keypoint in j) rows. Returns the counts."""
    work = item.job.work
    done = pairs_name(item.chunk) + ".json"
    if work.exists(done):
        return work.get_json(done)
    p = item.job.params
    K = item.job.working.K
    cache: dict[int, dict[str, np.ndarray] | None] = {}

    def features(pos: int) -> dict[str, np.ndarray] | None:
        if pos not in cache:
            name = features_name(pos)
            cache[pos] = work.get_arrays(name) if work.exists(name) else None
        return cache[pos]

    rows, proposed, kept = [], 0, 0
    for i, j in item.pairs:
        fi, fj = features(i), features(j)
        if fi is None or fj is None:
            continue
        m = sift_ratio_matches_flann(fi["desc"], fj["desc"], p.sift_ratio)
        proposed += len(m)
        if len(m) < MIN_PAIR_INLIERS:
            continue
        inl = essential_inliers(fi["xy"][m[:, 0]].astype(np.float64), fj["xy"][m[:, 1]].astype(np.float64), K,
                                PAIR_RANSAC_PX)
        if inl.sum() < MIN_PAIR_INLIERS:
            continue
        kept += 1
        m = m[inl]
        rows.append(np.column_stack([np.full(len(m), i), np.full(len(m), j), m]))
    matches = np.vstack(rows).astype(np.int64) if rows else np.zeros((0, 4), np.int64)
    work.put_arrays(pairs_name(item.chunk) + ".npz", matches=matches)
    meta = {"chunk": item.chunk, "pairs": len(item.pairs), "matched": kept, "proposed": proposed,
            "inliers": int(len(matches))}
    work.put_json(done, meta)
    return meta


def submodel_tracks(job: SparseJob, members: np.ndarray, blocks: list[int], chunks: list[int],
                    flow_pairs: list[list[int]]) -> TrackSet:
    """The tracks over a submodel's photos (``members`` (M,) sorted positions): the block tracks of those photos
    and the pairs' matches among them joined into tracks (connected components of the match graph; one holding
    two keypoints of one photo joins different points and is dropped), frames numbered 0..M-1."""
    work = job.work
    local = np.full(len(job.names), -1, np.int64)
    local[members] = np.arange(len(members))
    frames, tracks, xys, rgbs = [], [], [], []
    offset = 0
    for b in blocks:
        a = work.get_arrays(block_name(b) + ".npz")
        keep = local[a["photo"]] >= 0 if len(a["photo"]) else np.zeros(0, bool)
        frames.append(local[a["photo"][keep]])
        tracks.append(a["track"][keep] + offset)
        xys.append(a["xy"][keep])
        rgbs.append(a["rgb"][keep])
        offset += int(a["track"].max()) + 1 if len(a["track"]) else 0
    rows = [work.get_arrays(pairs_name(c) + ".npz")["matches"] for c in chunks]
    matches = np.vstack(rows) if rows else np.zeros((0, 4), np.int64)
    matches = matches[(local[matches[:, 0]] >= 0) & (local[matches[:, 1]] >= 0)] if len(matches) else matches
    if len(matches):
        photos = np.unique(matches[:, :2])
        feats = {int(pos): work.get_arrays(features_name(int(pos))) for pos in photos}
        start = {}
        total = 0
        for pos in photos:
            start[int(pos)] = total
            total += len(feats[int(pos)]["xy"])
        a = np.array([start[int(i)] for i in matches[:, 0]]) + matches[:, 2]
        b = np.array([start[int(j)] for j in matches[:, 1]]) + matches[:, 3]
        graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(total, total))
        _, label = connected_components(graph, directed=False)
        node_photo = np.repeat(photos, [len(feats[int(pos)]["xy"]) for pos in photos])
        matched = np.zeros(total, bool)
        matched[a] = matched[b] = True
        key = label.astype(np.int64) * (len(job.names) + 1) + node_photo
        _, first, counts = np.unique(key[matched], return_index=True, return_counts=True)
        bad = np.unique(label[matched][first[counts > 1]])
        keep = np.flatnonzero(matched & ~np.isin(label, bad))
        xy = np.concatenate([feats[int(pos)]["xy"] for pos in photos])[keep].astype(np.float64)
        xy, ok = measure_by_flow(job, node_photo[keep], label[keep], xy)
        keep = keep[ok]
        frames.append(local[node_photo[keep]])
        tracks.append(label[keep].astype(np.int64) + offset)
        xys.append(xy[ok])
        rgbs.append(np.concatenate([feats[int(pos)]["rgb"] for pos in photos])[keep])
    pairs = [PairStats(int(local[r[0]]), int(local[r[1]]), *r[2:]) for r in flow_pairs
             if local[r[0]] >= 0 and local[r[1]] >= 0]
    return tracks_from_observations(frames, tracks, xys, rgbs, len(members), pairs)


def measure_by_flow(job: SparseJob, photo: np.ndarray, track: np.ndarray, xy: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Re-measure matched keypoints: each track's observations (photo positions (N,), track ids (N,), SIFT pixels
    (N, 2)) followed by the optical flow from the track's first photo's keypoint into the others' images, seeded at
    their keypoints. Returns the pixels (N, 2) float64 (the first photo's unchanged) and a mask (N,) bool of those
    the flow kept (:func:`refine_by_flow`); a track left with one photo is dropped whole. Decodes the photos
    involved, one anchor photo and its targets at a time."""
    out = xy.copy()
    ok = np.ones(len(xy), bool)
    if len(xy) == 0:
        return out, ok
    order = np.lexsort((photo, track))
    first = np.ones(len(order), bool)
    first[1:] = track[order][1:] != track[order][:-1]
    anchor_of = np.empty(len(xy), np.int64)  # each observation's track's first observation
    anchor_of[order] = order[np.maximum.accumulate(np.where(first, np.arange(len(order)), 0))]
    is_anchor = anchor_of == np.arange(len(xy))
    grays = _Grays(job)
    for a_photo in np.unique(photo[is_anchor]):
        followers = np.flatnonzero(~is_anchor & (photo[anchor_of] == a_photo))
        gray_a = grays.get(int(a_photo))
        for q in np.unique(photo[followers]):
            rows = followers[photo[followers] == q]
            gray_q = grays.get(int(q))
            if gray_a is None or gray_q is None:
                ok[rows] = False
                continue
            out[rows], ok[rows] = refine_by_flow(gray_a, gray_q, xy[anchor_of[rows]], xy[rows], job.params.lk_window)
        grays.release(int(a_photo))
    followed = np.bincount(track[ok], minlength=int(track.max()) + 1)
    ok &= followed[track] >= 2
    return out, ok


def refine_by_flow(gray_i: np.ndarray, gray_j: np.ndarray, xy_i: np.ndarray, xy_j: np.ndarray, window: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Where the pyramidal Lucas-Kanade flow puts the points ``xy_i`` (N, 2) of gray_i in gray_j (H, W) uint8,
    starting from ``xy_j`` (N, 2) (their matches): (N, 2) float64 pixels and a mask (N,) bool of those it followed
    whose flow comes back to within :data:`FLOW_REMEASURE_PX` of the start (forward-backward) and lands within as
    much of the match."""
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
    a = xy_i.astype(np.float32).reshape(-1, 1, 2)
    b = xy_j.astype(np.float32).reshape(-1, 1, 2)
    size = (window, window)
    fwd, st, _ = cv2.calcOpticalFlowPyrLK(gray_i, gray_j, a, b.copy(), winSize=size, maxLevel=1, criteria=criteria,
                                          flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(gray_j, gray_i, fwd, a.copy(), winSize=size, maxLevel=1,
                                            criteria=criteria, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    fwd, back = fwd.reshape(-1, 2).astype(np.float64), back.reshape(-1, 2).astype(np.float64)
    ok = ((st.ravel() == 1) & (st2.ravel() == 1) & (np.linalg.norm(back - xy_i, axis=1) < FLOW_REMEASURE_PX)
          & (np.linalg.norm(fwd - xy_j, axis=1) < FLOW_REMEASURE_PX))
    return fwd, ok


class _Grays:
    """Grey working images of a job's photos, decoded on first use, kept until released (an anchor photo's targets
    are mostly the next anchors: a handful of images at a time)."""

    def __init__(self, job: SparseJob) -> None:
        self.job = job
        self.images: dict[int, np.ndarray | None] = {}

    def get(self, pos: int) -> np.ndarray | None:
        if pos not in self.images:
            self.images[pos] = self._decode(pos)
        return self.images[pos]

    def release(self, below: int) -> None:
        """Let go of the photos before position ``below`` (anchors come in increasing positions)."""
        for q in [q for q in self.images if q <= below]:
            del self.images[q]

    def _decode(self, pos: int) -> np.ndarray | None:
        job = self.job
        name = job.names[pos]
        raw = job.photos.raw([name]).get(name)
        if raw is None:
            return None
        intr = job.working if job.undistort else replace(job.working, dist=None)
        return cv2.cvtColor(working_image(raw[0], job.photos.working_size, intr), cv2.COLOR_BGR2GRAY)


@dataclass(frozen=True)
class SubmodelItem:
    """One submodel to map: its index, member photos (sorted), the blocks and pair chunks that hold their tracks,
    the flow's pair counts, the lens (None: given intrinsics, or self-calibrated from ``prior``), the GPS
    positions by photo name and the survey's UTM zone and origin."""

    job: SparseJob
    index: int
    members: tuple[int, ...]
    blocks: tuple[int, ...]
    chunks: tuple[int, ...]
    flow_pairs: tuple[tuple[int, ...], ...]
    seconds: tuple[float, float]
    lens: Lens | None
    prior: FocalPrior | None
    gps: dict[str, GeoPoint]
    gps_source: str
    altitude: str
    epsg: int
    origin: tuple[float, float, float]


def submodel_name(s: int) -> str:
    return f"submodels/{s:04d}"


def map_submodel(item: SubmodelItem) -> dict[str, Any]:
    """Map one submodel and place it in the survey's frame (module docstring); writes the model with its
    georeference. Returns its summary: photos, registered, lens, reprojection error, the GPS fit; ``failed``
    with the reason when the photos cannot be mapped (a submodel over featureless ground) or placed (``unplaced``: its
    GPS positions cannot place it)."""
    job, work = item.job, item.job.work
    done = submodel_name(item.index) + ".json"
    if work.exists(done):
        return work.get_json(done)
    t0 = time.perf_counter()
    members = np.asarray(item.members, np.int64)
    ts = submodel_tracks(job, members, list(item.blocks), list(item.chunks), [list(r) for r in item.flow_pairs])
    w, h = job.native_size
    stats = SelectionStats(decoded=len(members), selected=len(members), native_size=job.native_size,
                           working_size=(int(round(w * job.scale)), int(round(h * job.scale))), scale=job.scale)
    tr = Tracked(ts, stats, [int(m) for m in members], [None] * len(members), [job.names[m] for m in members],
                 item.seconds[0], item.seconds[1], [])
    lens = replace(item.lens, fixed=True) if item.lens is not None else None
    try:
        model = map_tracks(tr, job.intrinsics, job.params, None, item.prior, lens, all_keyframes=True)
        ref = _place(model, item)
    except (JobInputError, GeoreferenceError) as exc:
        meta = {"index": item.index, "photos": len(members), "failed": str(exc),
                "unplaced": isinstance(exc, GeoreferenceError)}
        work.put_json(done, meta)
        return meta
    work.put_object(submodel_name(item.index) + ".pkl", (model, ref))
    lens_out = model.lens
    meta = {"index": item.index, "photos": len(members), "registered": int(model.registered.sum()),
            "points": int(len(model.points)),
            "reprojection_error_px": model.report["reprojection_error_px"]["after_ba"]["mean"],
            "lens": None if lens_out is None else [lens_out.f, lens_out.k1, lens_out.k2, *map(float, lens_out.centre)],
            "gps_fit_rmse_m": ref.fit.rmse, "scale": ref.sim.s, "seconds": round(time.perf_counter() - t0, 3)}
    work.put_json(done, meta)
    return meta


def _place(model: SparseModel, item: SubmodelItem) -> Georeference:
    """The submodel moved into the survey's UTM frame by its GPS (and adjusted with the GPS as a prior when the
    parameters ask)."""
    positions = {f: item.gps[name] for f, name in enumerate(model.frame_name) if name in item.gps}
    ref = georeference(model, positions, item.gps_source, item.altitude, origin=np.asarray(item.origin),
                       epsg=item.epsg)
    apply(model, ref.sim, ref.describe())
    sigma = item.job.params.gps_prior_m
    if sigma is not None:
        res = gps_adjust(model, ref, sigma, item.job.params.ba_iterations)
        ref.notes.append(f"bundle adjustment with the GPS as a {sigma:g} m prior on the camera centres "
                         f"({res.iterations} iterations, {res.termination})")
    return ref


def load_submodel(work: WorkArea, s: int) -> tuple[SparseModel, Georeference]:
    """A mapped submodel and its georeference, as :func:`map_submodel` wrote them."""
    return work.get_object(submodel_name(s) + ".pkl")
