"""The mapping stage of a drone job: from a model in a level world frame (georeferenced or not), its
dense cloud and the frames' images to the products a drone mapper expects: orthophoto and DSM on one
grid, the cloud as LAZ, previews (see :mod:`workers.drone.surface`, :mod:`workers.drone.orthophoto`,
:mod:`workers.drone.mapfiles`).

The ground sampling distance (GSD) is the flight's own unless given: the median over the registered
frames of (the median depth of the sparse points a frame sees) / (its focal length in pixels), i.e. the
ground size of one pixel of the working images straight below the camera.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from .dense.views import View
from .georef import Georeference
from .orthophoto import Orthophoto, orthophoto
from .reconstruction import SparseModel
from .surface import Grid, grid_over, surface_model

ProgressFn = Callable[[float, str], None]


def flight_gsd(model: SparseModel) -> float:
    """The flight's ground sampling distance in world units per working-resolution pixel (see the module
    docstring). Raises ValueError when no registered frame sees a sparse point."""
    depths = []
    for f in np.flatnonzero(model.registered):
        pts = model.points[model.obs_point[model.obs_frame == f]]
        if len(pts) >= 10:
            z = pts @ model.R[f][2] + model.t[f][2]
            depths.append(float(np.median(z[z > 0])) if (z > 0).any() else np.nan)
    depths = np.asarray(depths)
    depths = depths[np.isfinite(depths)]
    if len(depths) == 0:
        raise ValueError("no registered frame sees the sparse points: no ground sampling distance")
    return float(np.median(depths)) / float(model.K[0, 0])


@dataclass
class MapProducts:
    """The grid, the DSM (H, W) float32 (NaN: nodata), the orthophoto (or None), and the report."""

    grid: Grid
    dsm: np.ndarray
    ortho: Orthophoto | None
    report: dict[str, Any] = field(default_factory=dict)


def make_products(model: SparseModel, ref: Georeference, points: np.ndarray, images: dict[int, np.ndarray],
                  gsd: float | None = None, with_ortho: bool = True, progress: ProgressFn | None = None
                  ) -> MapProducts:
    """DSM (and orthophoto) of ``model`` (already in ``ref``'s world frame) from ``points`` (N, 3) (the
    dense cloud in that frame) and ``images``: model frame -> (h, w, 3) uint8 BGR at the working resolution
    as the lens saw them (``model.intrinsics.dist`` says how; None: undistorted). ``gsd`` in world units
    (None: :func:`flight_gsd`).
    Raises ValueError when the cloud is empty or the grid would be too large."""
    if len(points) < 3:
        raise ValueError("the dense cloud is empty: no surface model")
    t0 = time.perf_counter()
    flight = flight_gsd(model)
    cell = float(gsd) if gsd is not None else flight
    grid = grid_over(points, cell)
    if progress is not None:
        progress(0.0, "surface model")
    dsm = surface_model(points, grid)
    t1 = time.perf_counter()
    ortho = None
    if with_ortho:
        views = [View.from_pose(model.frame_name[f], img, model.K, model.R[f], model.t[f])
                 for f, img in sorted(images.items()) if model.registered[f]]
        ortho = orthophoto(dsm, grid, views, progress, model.intrinsics.dist)
    t2 = time.perf_counter()
    unit = "m" if ref.georeferenced else "model units"
    report: dict[str, Any] = {
        "gsd": cell, "gsd_unit": unit, "flight_gsd": flight, "grid": {"width": grid.width, "height": grid.height},
        "covered_cells": int(np.isfinite(dsm).sum()),
        "area": float(np.isfinite(dsm).sum() * cell * cell),
        "dsm_height_range": [float(np.nanmin(dsm)), float(np.nanmax(dsm))] if np.isfinite(dsm).any() else None,
        "seconds": {"dsm": round(t1 - t0, 3), "orthophoto": round(t2 - t1, 3)},
    }
    if ortho is not None:
        report["orthophoto_frames"] = int(len(np.unique(ortho.source[ortho.source >= 0])))
        report["orthophoto_coverage"] = ortho.coverage
        report["seconds"]["orthophoto_steps"] = ortho.seconds
    return MapProducts(grid, dsm, ortho, report)
