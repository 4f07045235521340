"""How a survey's stills are cut into work: tracking blocks, the pairs matched across flight lines, and
overlapping submodels, all from the photos' order and GPS positions.

- **Blocks** (features and tracks, one task each): runs of the flight order in which each photo was taken
  near the one before (at most :data:`BLOCK_PHOTOS` photos a block): the paper's FAST + optical-flow tracks
  follow a block from photo to photo.
- **Pairs** (matched across flight lines, tasks of :data:`PAIRS_PER_TASK`): every photo with its GPS
  neighbours that optical flow did not follow it to (not the next or previous photo of its block): the
  photos of the next flight line, the end of a line and the start of the next. Their SIFT matches tie the
  lines together.
- **Submodels** (a sparse model each, one task each): photos clustered by position (k-means on the GPS,
  about ``submodel_photos`` a cluster: its *core*), each widened by every photo within ``overlap_m`` of
  the core (its members), so that neighbouring submodels share photos; merged afterwards by those shared
  photos and the GPS (:mod:`.merge`). This is the idea of OpenDroneMap's split-merge (cluster the photos,
  grow each cluster by a distance, reconstruct each, align them).

Positions are metres in the survey's local frame (UTM minus the origin) or, where a photo has no GPS, taken
from its neighbours in the flight order.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

BLOCK_PHOTOS = 24
"""Most photos one tracking task follows (a long flight line is cut into blocks; the pairs tie them)."""
PAIRS_PER_TASK = 48
"""Photo pairs one matching task matches."""
JUMP_STEPS = 2.5
"""A photo more than this many typical steps (the median distance between consecutive photos) from the one
before it starts a new block: optical flow does not follow such a jump."""
PAIR_STEPS = 2.6
"""Photos closer than this many typical steps are matched as a pair (a flight line's neighbour at 65 %
side overlap lies ~1.9 steps away at 75 % forward overlap; its diagonal neighbours ~2.1)."""
PAIR_NEIGHBOURS = 8
"""Most partners a photo is matched with (its nearest)."""
OVERLAP_NEIGHBOURS = 6
OVERLAP_FACTOR = 1.15
"""Default overlap between submodels: every photo within this factor times the median distance from a photo to its
:data:`OVERLAP_NEIGHBOURS`-th nearest photo joins a submodel next to it (in a lawnmower survey: the flight line on
each side and the next photos along it, so neighbouring submodels share photos in both directions)."""


@dataclass
class Submodel:
    """``core`` (C,) the photo positions it owns (its cluster), ``members`` (M,) core plus overlap, sorted;
    ``centre`` (2,) the core's mean position (m)."""

    core: np.ndarray
    members: np.ndarray
    centre: np.ndarray


@dataclass
class SurveyPlan:
    """The work of a survey of N stills: their ``xy`` (N, 2) positions (m), the typical ``step`` (m), the
    tracking ``blocks`` (lists of photo positions in flight order), the matched ``pairs`` (P, 2) int64
    (i < j), the ``submodels`` and which one calibrates the lens first (``reference``); ``notes`` in
    words for the report."""

    xy: np.ndarray
    step: float
    blocks: list[np.ndarray]
    pairs: np.ndarray
    submodels: list[Submodel]
    reference: int
    overlap_m: float
    notes: list[str] = field(default_factory=list)

    def block_of(self) -> np.ndarray:
        """(N,) the block each photo belongs to."""
        out = np.full(len(self.xy), -1, np.int64)
        for b, photos in enumerate(self.blocks):
            out[photos] = b
        return out

    def owner(self) -> np.ndarray:
        """(N,) the submodel whose core holds each photo."""
        out = np.full(len(self.xy), -1, np.int64)
        for s, sub in enumerate(self.submodels):
            out[sub.core] = s
        return out

    def report(self) -> dict:
        """JSON-able summary."""
        return {"photos": int(len(self.xy)), "typical_step_m": round(self.step, 3),
                "blocks": len(self.blocks), "pairs": int(len(self.pairs)), "submodels": len(self.submodels),
                "submodel_photos": [int(len(s.members)) for s in self.submodels],
                "submodel_core_photos": [int(len(s.core)) for s in self.submodels],
                "overlap_m": round(self.overlap_m, 2), "reference_submodel": self.reference, "notes": self.notes}


def fill_positions(xy: np.ndarray) -> tuple[np.ndarray, int]:
    """Positions (N, 2) with the rows that are NaN (no GPS) taken from their neighbours in the flight order
    (linear between the photos before and after, else the nearest); returns them and how many were filled.
    Raises ValueError when no photo has a position."""
    xy = np.array(xy, np.float64)
    known = np.isfinite(xy).all(axis=1)
    if not known.any():
        raise ValueError("no photo has a GPS position")
    idx = np.arange(len(xy))
    for d in range(2):
        xy[~known, d] = np.interp(idx[~known], idx[known], xy[known, d])
    return xy, int((~known).sum())


def typical_step(xy: np.ndarray) -> float:
    """The median distance (m) between consecutive photos that moved at all (0.5 m at least)."""
    if len(xy) < 2:
        return 1.0
    steps = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    moved = steps[steps > 1e-3]
    return max(float(np.median(moved)) if len(moved) else 1.0, 0.5)


def tracking_blocks(xy: np.ndarray, step: float, block_photos: int = BLOCK_PHOTOS) -> list[np.ndarray]:
    """Runs of the flight order without a jump of more than :data:`JUMP_STEPS` steps, cut into blocks of at
    most ``block_photos`` (the last blocks of a run evened out)."""
    n = len(xy)
    jumps = np.flatnonzero(np.linalg.norm(np.diff(xy, axis=0), axis=1) > JUMP_STEPS * step) + 1
    blocks = []
    for run in np.split(np.arange(n), jumps):
        parts = int(np.ceil(len(run) / block_photos))
        blocks += [b for b in np.array_split(run, parts) if len(b)]
    return blocks


def candidate_pairs(xy: np.ndarray, step: float, blocks: list[np.ndarray]) -> np.ndarray:
    """Pairs (P, 2) int64, i < j: each photo with up to :data:`PAIR_NEIGHBOURS` nearest photos within
    :data:`PAIR_STEPS` steps, leaving out the photo just before or after it in its own block (optical flow
    links those)."""
    n = len(xy)
    if n < 2:
        return np.zeros((0, 2), np.int64)
    tree = cKDTree(xy)
    k = min(PAIR_NEIGHBOURS + 1, n)
    dist, nb = tree.query(xy, k=k, distance_upper_bound=PAIR_STEPS * step)
    block = np.full(n, -1, np.int64)
    for b, photos in enumerate(blocks):
        block[photos] = b
    pairs = set()
    for i in range(n):
        for d, j in zip(dist[i], nb[i]):
            if not np.isfinite(d) or j == i or j >= n:
                continue
            if block[i] == block[j] and abs(int(j) - i) == 1:
                continue
            pairs.add((min(i, int(j)), max(i, int(j))))
    return np.array(sorted(pairs), np.int64).reshape(-1, 2)


def split_submodels(xy: np.ndarray, photos_per_submodel: int, overlap_m: float, seed: int = 0) -> list[Submodel]:
    """Clusters of about ``photos_per_submodel`` photos by position (k-means, k = ceil(N / size)), each with
    every photo within ``overlap_m`` of its core added; one submodel of every photo when N fits in one."""
    n = len(xy)
    k = int(np.ceil(n / max(photos_per_submodel, 1)))
    if k <= 1:
        allp = np.arange(n)
        return [Submodel(allp, allp, xy.mean(axis=0))]
    from scipy.cluster.vq import kmeans2

    # k-means++ start, a fixed seed: the same photos give the same split (a resumed job finds its submodels).
    _, label = kmeans2(xy, k, minit="++", seed=seed)
    tree = cKDTree(xy)
    subs = []
    for c in range(k):
        core = np.flatnonzero(label == c)
        if len(core) == 0:
            continue
        near = tree.query_ball_point(xy[core], overlap_m)
        members = np.unique(np.concatenate([core] + [np.asarray(m, np.int64) for m in near]))
        subs.append(Submodel(core, members, xy[core].mean(axis=0)))
    return subs


def reference_order(subs: list[Submodel]) -> list[int]:
    """Submodels in the order they are tried as the lens's reference: the most photos first, then the one
    nearest the survey's centre."""
    if not subs:
        return []
    mid = np.mean([s.centre for s in subs], axis=0)
    return sorted(range(len(subs)), key=lambda s: (-len(subs[s].members), float(np.linalg.norm(subs[s].centre - mid))))


def default_overlap(xy: np.ndarray, step: float) -> float:
    """The overlap of :data:`OVERLAP_FACTOR` (module docstring), at least two typical steps."""
    k = min(OVERLAP_NEIGHBOURS, len(xy) - 1)
    if k < 1:
        return 2.0 * step
    dist, _ = cKDTree(xy).query(xy, k=k + 1)
    return max(OVERLAP_FACTOR * float(np.median(dist[:, k])), 2.0 * step)


def plan_survey(xy: np.ndarray, photos_per_submodel: int, overlap_m: float | None = None) -> SurveyPlan:
    """The :class:`SurveyPlan` of stills at positions ``xy`` (N, 2) metres (NaN rows: no GPS) in flight order;
    ``overlap_m`` None: :func:`default_overlap`."""
    filled, missing = fill_positions(xy)
    notes = []
    if missing:
        notes.append(f"{missing} photo(s) without a GPS position placed between their neighbours in the flight order")
    step = typical_step(filled)
    blocks = tracking_blocks(filled, step)
    pairs = candidate_pairs(filled, step, blocks)
    overlap = float(overlap_m) if overlap_m is not None else default_overlap(filled, step)
    subs = split_submodels(filled, photos_per_submodel, overlap)
    if len(subs) > 1:
        notes.append(f"{len(filled)} photos in {len(subs)} submodels of about {photos_per_submodel} (submodel_photos), "
                     f"each with the photos within {overlap:.1f} m of it; merged by their shared photos and the GPS")
    return SurveyPlan(filled, step, blocks, pairs, subs, reference_order(subs)[0], overlap, notes)
