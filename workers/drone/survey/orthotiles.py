"""The orthophoto per ground tile (one task each): the tile's DSM with a margin (assembled from the surface tiles,
brought to the orthophoto's finer grid) seen from straight above, each cell from the frame that sees it best,
blended across seams (:func:`workers.drone.orthophoto.orthophoto_of`), the frames read at their own resolution
one at a time; the margin gives the visibility test the buildings just outside the tile and the blend the
colours across its edge, and is cut off before the tile is written.

Written per tile: RGBA (uint8; alpha 0 where no frame sees the ground or there is no height) and the frame each
cell came from (int32 model frame, -1: none).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..orthophoto import orthophoto_of
from ..surface import Grid
from .ground import footprint_mask, sub_grid
from .mapjob import MapJob, Pose
from .surface import tile_name


@dataclass(frozen=True)
class OrthoItem:
    """One tile: its (row, column), the DSM grid and the DSM window (r0, r1, c0, c1) of tile plus margin, the tile's
    own DSM window, the orthophoto cells per DSM cell, the surface tiles to read (with their DSM windows), the frames
    that may see it with their sharpness weights, and the footprints over it."""

    job: MapJob
    tile: tuple[int, int]
    dsm_grid: Grid
    window: tuple[int, int, int, int]
    core: tuple[int, int, int, int]
    factor: int
    sources: tuple[tuple[tuple[int, int], tuple[int, int, int, int]], ...]
    poses: tuple[Pose, ...]
    weights: tuple[float, ...]
    footprints: tuple[np.ndarray, ...]


def upsampled(dsm: np.ndarray, factor: int) -> np.ndarray:
    """A DSM window (h, w) float32 on a grid ``factor`` times finer (h f, w f): bilinear between cells that all have
    a height, the nearest cell's elsewhere, NaN where that cell has none."""
    if factor == 1:
        return dsm
    h, w = dsm.shape
    known = np.isfinite(dsm)
    filled = np.where(known, dsm, np.nanmedian(dsm) if known.any() else 0.0).astype(np.float32)
    # cv2.resize maps cell centres onto cell centres, as two grids with the same corner do
    smooth = cv2.resize(filled, (w * factor, h * factor), interpolation=cv2.INTER_LINEAR)
    near = cv2.resize(dsm, (w * factor, h * factor), interpolation=cv2.INTER_NEAREST)
    all_known = cv2.resize(cv2.erode(known.astype(np.uint8), np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE),
                           (w * factor, h * factor), interpolation=cv2.INTER_NEAREST).astype(bool)
    return np.where(all_known, smooth, near).astype(np.float32)


def ortho_tile(item: OrthoItem) -> dict[str, Any]:
    """Render one tile (module docstring); returns its counts: cells of the footprints' union and of those the ones
    with a colour, the frames used, the seconds of its steps."""
    job, work = item.job, item.job.work
    done = tile_name("ortho", item.tile) + ".json"
    if work.exists(done):
        return work.get_json(done)
    r0, r1, c0, c1 = item.window
    dsm = np.full((r1 - r0, c1 - c0), np.nan, np.float32)
    for tile, (a0, a1, b0, b1) in item.sources:
        part = work.get_arrays(tile_name("dsm", tile) + ".npz")["dsm"]
        y0, y1, x0, x1 = max(a0, r0), min(a1, r1), max(b0, c0), min(b1, c1)
        if y0 < y1 and x0 < x1:
            dsm[y0 - r0:y1 - r0, x0 - c0:x1 - c0] = part[y0 - a0:y1 - a0, x0 - b0:x1 - b0]
    f = item.factor
    fine = upsampled(dsm, f)
    dsm_win = sub_grid(item.dsm_grid, item.window)
    grid = Grid(dsm_win.x0, dsm_win.y0, dsm_win.gsd / f, dsm_win.width * f, dsm_win.height * f)
    cameras = [job.raw_camera(p) for p in item.poses]
    names = [p.name for p in item.poses]
    dist = job.intrinsics.dist
    # The orthophoto samples through a lens of up to five coefficients; a longer model is undistorted first.
    long_model = dist is not None and len(dist) > 5 and bool(np.any(np.asarray(dist)[5:]))

    def image(i: int) -> np.ndarray:
        raw = job.photos.raw([names[i]])[names[i]][0]
        return cv2.undistort(raw, cameras[i].K, dist) if long_model else raw

    ortho = orthophoto_of(cameras, np.asarray(item.weights), image, fine, grid, None, None if long_model else dist)
    q0, q1, p0, p1 = ((item.core[0] - r0) * f, (item.core[1] - r0) * f, (item.core[2] - c0) * f, (item.core[3] - c0) * f)
    rgba = ortho.rgba[q0:q1, p0:p1]
    frames = np.array([p.frame for p in item.poses] + [-1], np.int32)
    source = frames[ortho.source[q0:q1, p0:p1].astype(np.int64)]  # -1 indexes the trailing -1
    core_grid = Grid(grid.x0 + p0 * grid.gsd, grid.y0 - q0 * grid.gsd, grid.gsd, p1 - p0, q1 - q0)
    union = footprint_mask(core_grid, list(item.footprints))
    work.put_arrays(tile_name("ortho", item.tile) + ".npz", rgba=rgba, source=source)
    coloured = rgba[..., 3] > 0
    meta = {"tile": list(item.tile), "union_cells": int(union.sum()), "union_coloured": int((union & coloured).sum()),
            "coloured": int(coloured.sum()), "frames": int(len(np.unique(source[source >= 0]))),
            "seconds": ortho.seconds}
    work.put_json(done, meta)
    return meta
