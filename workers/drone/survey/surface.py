"""The dense stage's second half and the surface model, per ground tile (one task each): the depth maps of the
references that see the tile fused into points (:func:`workers.drone.dense.fuse`, the references in the model's
order, each starting points only at its pixels whose point falls in the tile or its margin), then the DSM of the
tile from the points of the tile and its margin (:func:`workers.drone.surface.surface_model`, covering the ground
the photos saw: the union of their footprints; where no dense point reaches, as where fewer than
``dense_min_views`` photos saw the ground, the sparse points' heights).

Written per tile: the tile's points (``x y z`` float32 world, colours, normals, views; those of its margin belong
to the neighbouring tile), its DSM cells (float32, NaN: nodata), a sample of its points for the preview. A point
belongs to the tile whose square holds it, so the tiles' points never repeat one another.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..dense import fuse
from ..surface import Grid, surface_model
from .depthmaps import depth_name
from .ground import footprint_mask
from .mapjob import MapJob, Pose

PREVIEW_POINTS_PER_TILE = 30_000
MARGIN_CELLS = 32
"""DSM cells around a tile whose points its surface model also uses (its fill and median filter see across)."""


def tile_name(kind: str, tile: tuple[int, int]) -> str:
    return f"tiles/{kind}/{tile[0]:04d}_{tile[1]:04d}"


@dataclass(frozen=True)
class SurfaceItem:
    """One tile: its (row, column), the DSM grid of the tile with its margin and where the tile lies in it (rows
    and columns, end exclusive), the world boxes (x0, x1, y0, y1) of the tile and of tile plus margin, the
    references that see it (in the model's order) with their neighbours' frames, the poses of all of those, and
    the footprints of the frames over it."""

    job: MapJob
    tile: tuple[int, int]
    grid: Grid
    core: tuple[int, int, int, int]
    bounds: tuple[float, float, float, float]
    margin_bounds: tuple[float, float, float, float]
    refs: tuple[int, ...]
    neighbours: tuple[tuple[int, ...], ...]
    poses: tuple[Pose, ...]
    footprints: tuple[np.ndarray, ...]
    sparse: np.ndarray
    """(M, 3) the sparse model's points over the tile and its margin (where no dense point reaches)."""
    reach: int
    """DSM cells the surface model reaches beyond the footprints' union (their ground height is an estimate)."""
    ground_z: float
    """The median ground height below the frames over the tile (each frame's from its sparse points): the tile's
    heights where neither a dense nor a sparse point reaches it (a survey's rim, seen by one photo)."""


def _world_xy(camera, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World x, y (h, w) float64 of every pixel of a depth map (h, w) (z along the optical axis; a pinhole camera
    without skew or distortion, as the dense views are)."""
    h, w = depth.shape
    K, R, t = camera.K, camera.R, camera.t
    d = depth.astype(np.float64)
    xc = (np.arange(w)[None, :] - K[0, 2]) / K[0, 0] * d - t[0]
    yc = (np.arange(h)[:, None] - K[1, 2]) / K[1, 1] * d - t[1]
    zc = d - t[2]
    return R[0, 0] * xc + R[1, 0] * yc + R[2, 0] * zc, R[0, 1] * xc + R[1, 1] * yc + R[2, 1] * zc


def _inside(xy: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray:
    x0, x1, y0, y1 = box
    return (xy[:, 0] >= x0) & (xy[:, 0] < x1) & (xy[:, 1] >= y0) & (xy[:, 1] < y1)


def surface_tile(item: SurfaceItem) -> dict[str, Any]:
    """Fuse and model one tile (module docstring); returns its counts: points, DSM cells with a height, cells of the
    footprints' union, and of those the ones with a height, the height range, the fusion's seconds."""
    job, work, p = item.job, item.job.work, item.job.params
    done = tile_name("surface", item.tile) + ".json"
    if work.exists(done):
        return work.get_json(done)
    wanted = sorted(set(item.refs) | {n for nb in item.neighbours for n in nb})
    have = [f for f in wanted if work.exists(depth_name(f) + ".npz")]
    views = job.dense_views([q for q in item.poses if q.frame in set(have)])
    frames = [f for f in have if f in views]
    index = {f: i for i, f in enumerate(frames)}
    depths = [work.get_arrays(depth_name(f) + ".npz")["depth"] for f in frames]
    refs = [f for f in item.refs if f in index]
    nbs = [[] for _ in frames]
    for f, nb in zip(item.refs, item.neighbours):
        if f in index:
            nbs[index[f]] = [index[n] for n in nb if n in index]
    masks: list[np.ndarray | None] = [None] * len(frames)
    x0, x1, y0, y1 = item.margin_bounds
    for f in refs:
        x, y = _world_xy(views[f].camera, depths[index[f]])
        masks[index[f]] = (depths[index[f]] > 0) & (x >= x0) & (x < x1) & (y >= y0) & (y < y1)
    cloud = fuse([views[f] for f in frames], depths, nbs, p.dense_min_views, p.dense_max_reprojection,
                 p.dense_max_depth_error, references=[index[f] for f in refs], masks=masks)
    union = footprint_mask(item.grid, list(item.footprints))
    k = 2 * item.reach + 1
    extent = cv2.dilate(union.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))).astype(bool)
    dsm = surface_model(cloud.points, item.grid, extent=extent, support=item.sparse, ground_z=item.ground_z)
    r0, r1, c0, c1 = item.core
    dsm, union = dsm[r0:r1, c0:c1], union[r0:r1, c0:c1]
    mine = _inside(cloud.points, item.bounds)
    rng = np.random.default_rng(item.tile[0] * 100_003 + item.tile[1])
    count = int(mine.sum())
    sample = np.flatnonzero(mine)
    if count > PREVIEW_POINTS_PER_TILE:
        sample = np.sort(rng.choice(sample, PREVIEW_POINTS_PER_TILE, replace=False))
    work.put_arrays(tile_name("points", item.tile) + ".npz", points=cloud.points[mine], colors=cloud.colors[mine],
                    normals=cloud.normals[mine], views=cloud.views[mine])
    work.put_arrays(tile_name("sample", item.tile) + ".npz", points=cloud.points[sample], colors=cloud.colors[sample])
    work.put_arrays(tile_name("dsm", item.tile) + ".npz", dsm=dsm.astype(np.float32))
    known = np.isfinite(dsm)
    meta = {"tile": list(item.tile), "points": count, "references": len(refs),
            "ground_level_only": not len(cloud) and not len(item.sparse),
            "dsm_cells": int(known.sum()), "union_cells": int(union.sum()), "union_with_height": int((known & union).sum()),
            "height_range": [float(np.nanmin(dsm)), float(np.nanmax(dsm))] if known.any() else None,
            "z_range": [float(cloud.points[mine, 2].min()), float(cloud.points[mine, 2].max())] if count else None,
            "views_sum": int(cloud.views[mine].astype(np.int64).sum()), "views_3plus": int((cloud.views[mine] >= 3).sum())}
    work.put_json(done, meta)
    return meta
