"""The dense pass of a reconstruction: a depth map per reference frame against its best neighbours, fused
into one cloud; the depth maps' PNGs and a JSON-able report."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from ..export import depth_file_name, depth_png
from ..params import ReconstructionParams
from .depth import depth_map
from .fusion import DenseCloud, fuse
from .neighbours import depth_range, select_neighbours
from .views import View

ProgressFn = Callable[[float, str], None]


@dataclass
class DenseResult:
    """What :func:`densify_views` made: the fused ``cloud``, the reference frames' ``names`` and ``depths``
    ((h, w) float32 each, 0 = none, at the dense resolution), their 16-bit ``pngs`` and a JSON-able ``report``."""

    cloud: DenseCloud
    names: list[str]
    depths: list[np.ndarray]
    pngs: list[bytes]
    report: dict[str, Any]


def reference_frames(registered: np.ndarray, count: int) -> np.ndarray:
    """Indices (M,) int64 of at most ``count`` registered frames (registered (F,) bool), evenly spread."""
    reg = np.flatnonzero(registered)
    if len(reg) <= count:
        return reg
    pick = np.unique(np.rint(np.linspace(0, len(reg) - 1, count)).astype(np.int64))
    return reg[pick]


def densify_views(views: Sequence[View], points: np.ndarray, seen: Sequence[np.ndarray], p: ReconstructionParams,
                  progress: ProgressFn | None = None) -> DenseResult:
    """The dense pass over posed views (each one its own reference, the others its candidate neighbours), in this
    process (a job's dense pass runs as tasks per depth map and per ground tile, :mod:`workers.drone.survey`):
    points (P, 3) the sparse points, seen[i] the indices of those view i sees (neighbour choice and depth
    range); p the ``dense_*`` settings (:class:`~workers.drone.params.ReconstructionParams` or anything
    with those attributes)."""
    t_all = time.perf_counter()
    views = list(views)
    points = np.asarray(points, np.float64).reshape(-1, 3)
    radius = p.dense_window // 2
    depths: dict[int, np.ndarray] = {}
    neighbours: dict[int, list[int]] = {}
    items: list[dict[str, Any]] = []
    for i, view in enumerate(views):
        if progress is not None:
            progress(0.9 * i / len(views), f"dense depth {i + 1}/{len(views)}")
        nb = select_neighbours(views, points, seen, i, p.dense_neighbours)
        rng_ = depth_range(view.camera, points[seen[i]] if len(seen[i]) >= 10 else points)
        item: dict[str, Any] = {"frame": view.camera.name, "neighbours": [views[j].camera.name for j in nb]}
        items.append(item)
        if not nb or rng_ is None:
            item["skipped"] = "no other frame shares sparse points" if not nb else "too few sparse points in view"
            continue
        near, far = rng_
        dm = depth_map(view, [views[j] for j in nb], near, far, p.dense_planes, radius,
                       min(p.dense_best_k, len(nb)), p.dense_min_texture, p.dense_max_cost, p.dense_aggregation,
                       coarse_to_fine=p.dense_coarse_to_fine)
        depths[i] = dm.depth
        neighbours[i] = nb
        png, scale = depth_png(dm.depth, far)
        item.update(near=near, far=far, seconds=round(dm.seconds, 3), valid_fraction=float((dm.depth > 0).mean()),
                    file=depth_file_name(view.camera.name), depth_scale=scale, png=png)
    if progress is not None:
        progress(0.9, "dense fusion")
    t0 = time.perf_counter()
    done = list(depths)
    idx = {f: i for i, f in enumerate(done)}
    cloud = fuse([views[f] for f in done], [depths[f] for f in done],
                 [[idx[g] for g in neighbours[f] if g in idx] for f in done], p.dense_min_views,
                 p.dense_max_reprojection, p.dense_max_depth_error)
    t_fuse = time.perf_counter() - t0
    pngs = [items[f].pop("png") for f in done]
    secs = [items[f]["seconds"] for f in done]
    w, h = views[0].camera.size
    report = {
        "reference_frames": len(views),
        "depth_maps": len(done),
        "resolution": [int(w), int(h)],
        "planes": p.dense_planes, "window": p.dense_window, "neighbours": p.dense_neighbours,
        "best_k": p.dense_best_k, "aggregation": p.dense_aggregation, "coarse_to_fine": p.dense_coarse_to_fine,
        "min_views": p.dense_min_views,
        "points": len(cloud),
        "sparse_points": int(len(points)),
        "dense_to_sparse": float(len(cloud) / max(len(points), 1)),
        "views_per_point": {"mean": float(cloud.views.mean()) if len(cloud) else None,
                            "at_least_3": float((cloud.views >= 3).mean()) if len(cloud) else None},
        "seconds_per_depth_map": _summary_stats(secs),
        "seconds_fusion": round(t_fuse, 3),
        "seconds_total": round(time.perf_counter() - t_all, 3),
        "depth_png": "depth.zip holds <frame>.png per depth map: 16-bit, depth = level * depth_scale (model units, "
                     "z along the optical axis), 0 = no depth; pixels at the dense resolution",
        "frames": items,
    }
    if progress is not None:
        progress(1.0, "dense fusion")
    return DenseResult(cloud, [views[f].camera.name for f in done], [depths[f] for f in done], pngs, report)


def _summary_stats(values: Sequence[float]) -> dict[str, Any]:
    """{'mean', 'median', 'max'} of a list of numbers (None when empty)."""
    a = np.asarray(values, np.float64)
    if len(a) == 0:
        return {"mean": None, "median": None, "max": None}
    return {"mean": float(a.mean()), "median": float(np.median(a)), "max": float(a.max())}
