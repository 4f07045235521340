"""One reference frame's depth map: the ZNCC sweep over planes uniform in inverse depth, coarse to fine or
with semi-global aggregation, the sub-plane winner turned into depth."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from workers.sweep import costs

from .homography import sweep_geometry
from .sweep import zncc_sweep
from .tiles import coarse_windows, sweep_tiles, tile_map
from .views import View


@dataclass
class DepthMap:
    """A reference frame's depth: ``depth`` (h, w) float32 (z, model units; 0 = none), ``cost`` (h, w)
    float32 (the winning plane's cost; inf = none), near/far of the sweep (model units), the neighbours' names
    and the wall ``seconds`` it took."""

    depth: np.ndarray
    cost: np.ndarray
    near: float
    far: float
    neighbours: list[str]
    seconds: float = 0.0


def inverse_depth_planes(near: float, far: float, planes: int) -> np.ndarray:
    """(planes,) float64 inverse depths, uniform from 1/near (plane 0) to 1/far."""
    if not 0 < near < far:
        raise ValueError(f"needs 0 < near < far, got near={near}, far={far}")
    return np.linspace(1.0 / near, 1.0 / far, int(planes))


def depth_map(ref: View, neighbours: Sequence[View], near: float, far: float, planes: int = 128, radius: int = 2,
              k: int = 4, min_std: float = 1.5, max_cost: float = 0.5, aggregation: str = "window",
              sgm_p1: float = 0.05, sgm_p2: float = 0.4, coarse_to_fine: bool = False, margin: int = 4,
              coarse_confidence: float = 0.3) -> DepthMap:
    """Depth map of ``ref`` from ``neighbours`` (all one image size) by the ZNCC plane sweep.

    near, far: the depth range (model units); planes: planes uniform in inverse depth; radius, k, min_std:
    :func:`.sweep.zncc_sweep`; max_cost: pixels whose winning cost (mean ``1 - ZNCC`` of the best k) is above get
    no depth; aggregation: ``"window"`` (the ZNCC window alone, streamed, low memory) or ``"sgm"``
    (the ZNCC volume smoothed by 8-path semi-global aggregation with penalties ``sgm_p1``/``sgm_p2`` in cost
    units, :func:`workers.sweep.costs.semi_global`; holds the (h, w, planes) volume). coarse_to_fine: first
    the same sweep on every other plane at half resolution, then at full resolution, tile by tile, only the planes
    within ``margin`` of the coarse winners whose cost is at most ``coarse_confidence`` (:mod:`.tiles`); a winner
    on the edge of its tile's range is dropped (the minimum may lie beyond). Returns the :class:`DepthMap` at
    ``ref``'s size."""
    if aggregation not in ("window", "sgm"):
        raise ValueError(f"aggregation must be 'window' or 'sgm', got {aggregation!r}")
    if not neighbours:
        raise ValueError("a depth map needs at least one neighbour")
    t0 = time.perf_counter()
    sizes = {v.camera.size for v in neighbours}
    if len(sizes) != 1:
        raise ValueError(f"neighbours differ in size: {sorted(sizes)}")
    s_planes = inverse_depth_planes(near, far, planes)
    Q, B = sweep_geometry(ref, neighbours)
    imgs = np.stack([v.gray() for v in neighbours])
    ref_gray = ref.gray()
    tiles = None
    h, w = ref_gray.shape
    P = len(s_planes)
    if coarse_to_fine and min(h, w) >= 16:
        ref_c = ref.scaled(0.5)
        nbr_c = [v.scaled(0.5) for v in neighbours]
        Qc, Bc = sweep_geometry(ref_c, nbr_c)
        # every other plane: at half the resolution a plane step moves a pixel as far as one step at full
        best_c, value_c, _, _ = zncc_sweep(ref_c.gray(), np.stack([v.gray() for v in nbr_c]), Qc, Bc,
                                           s_planes[::2], radius, k, min_std)
        best_c = np.where(best_c >= 0, 2 * best_c, -1)
        windows = coarse_windows(best_c, value_c, h, w, P, margin, coarse_confidence)
        tiles = sweep_tiles(h, w, P, windows)
        # a tile where the coarse search is sure of nothing searches the planes the sure pixels of the whole
        # image use (1st to 99th percentile, widened by twice the margin); all planes when there are none
        sure = (best_c >= 0) & (value_c <= coarse_confidence)
        g0, g1 = 0, P - 1
        if sure.sum() >= 100:
            q0, q1 = np.percentile(best_c[sure], [1, 99])
            g0, g1 = max(0, int(q0) - 2 * margin), min(P - 1, int(np.ceil(q1)) + 2 * margin)
        covered = np.zeros((h, w), bool)
        for y0, y1, x0, x1, _, _ in tiles:
            covered[y0:y1, x0:x1] = True
        rest = [(t[0], t[1], t[2], t[3], g0, g1) for t in sweep_tiles(h, w, P, None)
                if not covered[t[0]:t[1], t[2]:t[3]].any()]
        tiles = np.vstack([tiles, np.asarray(rest, np.int64).reshape(-1, 6)])
    best, value, offset, volume = zncc_sweep(ref_gray, imgs, Q, B, s_planes, radius, k, min_std,
                                             keep_volume=aggregation == "sgm", tiles=tiles)
    if aggregation == "sgm":
        agg = costs.semi_global(np.where(np.isfinite(volume), volume, np.float32(2.0)).astype(np.float32),
                                sgm_p1, sgm_p2, 8)
        agg[~np.isfinite(volume)] = np.inf
        best, _, offset = costs.winner(agg)
        value = np.take_along_axis(volume, np.maximum(best, 0)[:, :, None], 2)[:, :, 0]
        value[best < 0] = np.inf
        del agg, volume
    if tiles is not None:
        # a winner on a tile's first or last plane (not the sweep's) may be a minimum cut off by the range
        j0, j1 = tile_map(tiles, h, w)
        cut = ((best == j0) & (j0 > 0)) | ((best == j1) & (j1 < P - 1))
        value = np.where(cut, np.float32(np.inf), value)
    depth = planes_to_depth(best, offset, s_planes)
    keep = np.isfinite(value) & (value <= max_cost) & (depth > 0)
    depth = np.where(keep, depth, 0.0).astype(np.float32)
    return DepthMap(depth, np.where(keep, value, np.inf).astype(np.float32), float(near), float(far),
                    [v.camera.name for v in neighbours], time.perf_counter() - t0)


def planes_to_depth(best: np.ndarray, offset: np.ndarray, s_planes: np.ndarray) -> np.ndarray:
    """Winner plane (h, w) int32 (-1 = none) and sub-plane offset (h, w) float32 -> depth (h, w) float32
    (0 = none), interpolating linearly in inverse depth between planes."""
    s_planes = np.asarray(s_planes, np.float64)
    P = len(s_planes)
    j = np.clip(best, 0, P - 1).astype(np.float64) + (offset if P > 1 else 0.0)
    step = (s_planes[-1] - s_planes[0]) / max(P - 1, 1)
    s = s_planes[0] + j * step
    with np.errstate(divide="ignore"):
        depth = np.where((best >= 0) & (s > 0), 1.0 / s, 0.0)
    return depth.astype(np.float32)
