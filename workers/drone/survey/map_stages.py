"""The dense cloud and the map products, stage by stage: a depth map per reference frame (every registered frame
unless ``dense_frames`` asks for fewer), then per ground tile the fusion and the surface model, then per ground
tile the orthophoto; each stage's work as tasks (:mod:`.depthmaps`, :mod:`.surface`, :mod:`.orthotiles`) through
the job's :class:`~.stages.Stages`, the results left as tiles in the work area for :mod:`.products` to write."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from workers.common.jobctx import JobInputError

from ..dense import DenseCloud
from ..dense.pipeline import reference_frames
from ..geometry import camera_centre
from ..orthophoto import BLEND_REACH
from ..params import ReconstructionParams
from ..reconstruction import SparseModel
from .depthmaps import depth_items, depth_maps, depth_name, plan_depth_maps, pose_of
from .ground import GroundPlan, footprints, frame_ground_heights, overlapping, plan_ground, sub_grid
from .mapjob import MapJob
from .orthotiles import OrthoItem, ortho_tile
from .photos import PhotoSource
from .products import MapTiles
from .stages import Stages
from .surface import MARGIN_CELLS, SurfaceItem, surface_tile, tile_name

RELIEF_MARGIN = 0.15
"""The orthophoto's visibility test looks this share of the camera's height above the ground beyond its tile (a
building there may hide the tile's ground)."""
FOOTPRINT_SLACK = 0.05
"""The surface model reaches this share of the camera's height above the ground beyond the footprints' union: the
footprints are cast on an estimated ground height, and a self-calibrated lens bends the ground of a nadir survey by
decimetres (a 0.7 m error at 60 m moves a footprint's edge by ~0.5 m); the orthophoto colours what the images show."""


@dataclass
class DenseMap:
    """What the dense and map stages made: the tiles (:class:`~.products.MapTiles`), the depth maps written (their
    work-area PNG names and names in depth.zip), the reports ``dense`` and ``mapping``."""

    tiles: MapTiles
    depth_pngs: list[tuple[str, str]]
    dense: dict[str, Any]
    low: np.ndarray
    """(3,) the least x, y, z of the dense points (world frame)."""
    mapping: dict[str, Any] = field(default_factory=dict)

    @property
    def points(self) -> int:
        return int(self.dense["points"])

    def cloud(self) -> DenseCloud:
        """Every dense point at once (tests and benchmarks; a survey's job writes them tile by tile)."""
        parts = list(self.tiles.point_chunks())
        if not parts:
            return DenseCloud(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8), np.zeros((0, 3), np.float32),
                              np.zeros(0, np.uint8))
        return DenseCloud(*(np.concatenate([p[k] for p in parts]) for k in ("points", "colors", "normals", "views")))


def dense_and_map(stages: Stages, model: SparseModel, photos: PhotoSource, params: ReconstructionParams,
                  georeferenced: bool, with_ortho: bool, gsd: float | None, max_pixels: int,
                  sharpness: dict[int, float], span: tuple[float, float]) -> DenseMap:
    """The dense and map stages of a model in a level world frame (georeferenced, or levelled without GPS);
    ``gsd`` the orthophoto's cell asked for (world units; None: the photos' own), ``sharpness`` each photo's
    (position -> Laplacian variance) where already known. Raises JobInputError when fewer than two frames are
    registered or the map would exceed ``max_pixels``."""
    job = MapJob(stages.work, photos, params, model.intrinsics)
    refs = reference_frames(model.registered, params.dense_frames if params.dense_frames is not None
                            else int(model.registered.sum()))
    if len(refs) < 2:
        raise JobInputError(f"a dense reconstruction needs two registered frames; {len(refs)} registered")
    unit = "m" if georeferenced else "model units"
    below = frame_ground_heights(model)
    prints = footprints(model, heights=below)
    try:  # before any depth map: a map too large for the service's limit is refused at once
        ground = plan_ground(model, prints, gsd, params.dense_scale, unit, max_pixels, stages.fanout.parallelism)
    except ValueError as exc:
        raise JobInputError(f"map products: {exc}") from None
    lo, hi = span
    cut1, cut2 = lo + 0.62 * (hi - lo), lo + 0.8 * (hi - lo)
    merged = bool(model.report.get("submodel_alignment"))
    specs, skipped = stages.once("dense plan", lambda: plan_depth_maps(model, job, refs, by_view=merged), lo)
    metas = stages.map("dense depth", depth_maps, depth_items(job, specs, model, stages.fanout.parallelism), (lo, cut1),
                       finished=lambda it: _found_depths(stages, it), count=lambda it: len(it.refs))
    depth = [m for block in metas for m in block]
    made = [m for m in depth if "skipped" not in m]
    neighbours = {m["model_frame"]: tuple(m["neighbour_frames"]) for m in made}
    tiles = [t for t in ground.tiles() if overlapping(prints, ground.bounds(t))]
    above = _height_above_ground(model, below)
    reach = int(math.ceil(FOOTPRINT_SLACK * above / ground.dsm.gsd))
    surface = stages.map("surface model", surface_tile, [_surface_item(job, model, ground, t, prints, neighbours, reach,
                                                                       below) for t in tiles], (cut1, cut2),
                         finished=lambda it: stages.found(tile_name("surface", it.tile)), unit="tiles")
    maps = MapTiles(stages.work, ground, tiles)
    dense = _dense_report(params, refs, depth, skipped, surface, len(model.points), stages, model)
    zs = [m["z_range"][0] for m in surface if m["z_range"] is not None]
    g = ground.dsm
    low = np.array([g.x0, g.y0 - g.height * g.gsd, min(zs) if zs else 0.0])
    out = DenseMap(maps, [(depth_name(m["model_frame"]) + ".png", m["file"]) for m in made], dense, low)
    if with_ortho:
        weights = _weights(model, sharpness, depth)
        ortho = stages.map("orthophoto", ortho_tile, [_ortho_item(job, model, ground, t, tiles, prints, weights, above)
                                                       for t in tiles], (cut2, hi),
                           finished=lambda it: stages.found(tile_name("ortho", it.tile)), unit="tiles")
    else:
        ortho = []
    out.mapping = _mapping_report(ground, surface, ortho, unit)
    return out


def _found_depths(stages: Stages, item) -> list[dict[str, Any]] | None:
    names = [depth_name(r.pose.frame) + ".json" for r in item.refs]
    if not all(stages.work.exists(n) for n in names):
        return None
    return [stages.work.get_json(n) for n in names]


def _height_above_ground(model: SparseModel, heights: np.ndarray) -> float:
    """The registered cameras' median height above the ground below them (world units; ``heights``: each frame's
    ground height, :func:`workers.drone.survey.ground.frame_ground_heights`)."""
    reg = np.flatnonzero(model.registered)
    return float(np.median([camera_centre(model.R[f], model.t[f])[2] - heights[f] for f in reg]))


def _surface_item(job: MapJob, model: SparseModel, ground: GroundPlan, tile: tuple[int, int],
                  prints: dict[int, np.ndarray], neighbours: dict[int, tuple[int, ...]], reach: int,
                  below: np.ndarray) -> SurfaceItem:
    """``below``: each frame's ground height (:func:`workers.drone.survey.ground.frame_ground_heights`)."""
    window = ground.window(tile, MARGIN_CELLS)
    core = ground.window(tile)
    margin_m = MARGIN_CELLS * ground.dsm.gsd
    x0, x1, y0, y1 = ground.bounds(tile, margin_m)
    over = overlapping(prints, (x0, x1, y0, y1))
    refs = [f for f in over if f in neighbours]
    frames = sorted(set(refs) | {n for f in refs for n in neighbours[f]})
    pts = model.points
    sparse = pts[(pts[:, 0] >= x0) & (pts[:, 0] < x1) & (pts[:, 1] >= y0) & (pts[:, 1] < y1)]
    return SurfaceItem(job, tile, sub_grid(ground.dsm, window),
                       (core[0] - window[0], core[1] - window[0], core[2] - window[2], core[3] - window[2]),
                       ground.bounds(tile), (x0, x1, y0, y1), tuple(refs),
                       tuple(neighbours[f] for f in refs), tuple(pose_of(model, f) for f in frames),
                       tuple(prints[f] for f in over), sparse, reach, float(np.nanmedian(below[over])))


def _weights(model: SparseModel, sharpness: dict[int, float], depth: list[dict[str, Any]]) -> dict[int, float]:
    """Each registered frame's orthophoto weight: the square root of its sharpness over the median frame's (1 where
    unknown)."""
    sharp = {}
    for f in np.flatnonzero(model.registered):
        pos = int(model.frame_index[f])
        if pos in sharpness:
            sharp[int(f)] = sharpness[pos]
    for m in depth:
        if "sharpness" in m:
            sharp.setdefault(m["model_frame"], m["sharpness"])
    median = float(np.median(list(sharp.values()))) if sharp else 1.0
    return {f: math.sqrt(v / max(median, 1e-9)) for f, v in sharp.items()}


def _ortho_item(job: MapJob, model: SparseModel, ground: GroundPlan, tile: tuple[int, int], tiles: list,
                prints: dict[int, np.ndarray], weights: dict[int, float], above: float) -> OrthoItem:
    relief = RELIEF_MARGIN * above
    margin = max(int(math.ceil(relief / ground.dsm.gsd)), int(math.ceil(BLEND_REACH / ground.factor)))
    window = ground.window(tile, margin)
    g = ground.dsm
    bounds = (g.x0 + window[2] * g.gsd, g.x0 + window[3] * g.gsd, g.y0 - window[1] * g.gsd, g.y0 - window[0] * g.gsd)
    frames = overlapping(prints, bounds)
    sources = tuple((t, ground.window(t)) for t in tiles if _meets(ground.window(t), window))
    return OrthoItem(job, tile, g, window, ground.window(tile), ground.factor, sources,
                     tuple(pose_of(model, f) for f in frames), tuple(weights.get(f, 1.0) for f in frames),
                     tuple(prints[f] for f in overlapping(prints, ground.bounds(tile))))


def _meets(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> bool:
    return a[0] < b[1] and b[0] < a[1] and a[2] < b[3] and b[2] < a[3]


def _dense_report(params: ReconstructionParams, refs: np.ndarray, depth: list[dict[str, Any]], skipped: list,
                  surface: list[dict[str, Any]], sparse_points: int, stages: Stages, model: SparseModel) -> dict[str, Any]:
    """The report's ``dense`` part (as the whole-model dense pass gave it, per tile sums)."""
    made = [m for m in depth if "skipped" not in m]
    points = sum(m["points"] for m in surface)
    views = sum(m["views_sum"] for m in surface)
    secs = np.array([m["seconds"] for m in made]) if made else np.zeros(0)
    registered = int(model.registered.sum())
    w, h = model.width, model.height
    out = {
        "reference_frames": int(len(refs)), "registered_frames": registered,
        "depth_maps": len(made), "resolution": [int(round(w * params.dense_scale)), int(round(h * params.dense_scale))],
        "planes": params.dense_planes, "window": params.dense_window, "neighbours": params.dense_neighbours,
        "best_k": params.dense_best_k, "aggregation": params.dense_aggregation,
        "coarse_to_fine": params.dense_coarse_to_fine, "min_views": params.dense_min_views,
        "points": points, "sparse_points": sparse_points, "dense_to_sparse": points / max(sparse_points, 1),
        "views_per_point": {"mean": views / points if points else None,
                            "at_least_3": sum(m["views_3plus"] for m in surface) / points if points else None},
        "seconds_per_depth_map": {"mean": float(secs.mean()) if len(secs) else None,
                                  "median": float(np.median(secs)) if len(secs) else None,
                                  "max": float(secs.max()) if len(secs) else None},
        "seconds_fusion": stages.records.get("surface model", {}).get("seconds"),
        "seconds_total": round(sum(stages.records.get(k, {}).get("seconds", 0.0)
                                   for k in ("dense plan", "dense depth", "surface model")), 3),
        "tiles": len(surface),
        "depth_png": "depth.zip holds <frame>.png per depth map: 16-bit, depth = level * depth_scale (model units, "
                     "z along the optical axis), 0 = no depth; pixels at the dense resolution",
        "frames": [{k: v for k, v in m.items() if k not in ("model_frame", "neighbour_frames", "sharpness")}
                   for m in depth] + list(skipped),
    }
    if len(refs) < registered:
        out["note"] = (f"dense_frames={params.dense_frames}: depth maps of {len(refs)} of the {registered} registered "
                       "frames (evenly spread); the others are not in the dense cloud and the surface model")
    return out


def _mapping_report(ground: GroundPlan, surface: list[dict[str, Any]], ortho: list[dict[str, Any]], unit: str
                    ) -> dict[str, Any]:
    """The report's ``mapping`` part: grids, cell sizes and why, tiles, coverage of the photos' footprints."""
    o = ground.ortho
    union_dsm = sum(m["union_cells"] for m in surface)
    dsm_cells = sum(m["dsm_cells"] for m in surface)
    ranges = [m["height_range"] for m in surface if m["height_range"] is not None]
    out: dict[str, Any] = {
        "gsd": o.gsd, "gsd_unit": unit, "flight_gsd": ground.photo_gsd, **ground.report(),
        "grid": {"width": o.width, "height": o.height}, "dsm_grid": {"width": ground.dsm.width,
                                                                     "height": ground.dsm.height},
        "covered_cells": dsm_cells, "area": dsm_cells * ground.dsm.gsd ** 2,
        "dsm_height_range": [min(r[0] for r in ranges), max(r[1] for r in ranges)] if ranges else None,
        "coverage": {"footprint_union_area": union_dsm * ground.dsm.gsd ** 2,
                     "dsm": sum(m["union_with_height"] for m in surface) / union_dsm if union_dsm else None},
    }
    level = [m["tile"] for m in surface if m.get("ground_level_only")]
    if level:
        out["tiles_at_ground_level"] = {
            "tiles": level, "note": "no dense or sparse point reached these tiles (the survey's rim, seen by fewer "
                                    "photos than a point needs): their heights are the ground level below the photos "
                                    "over them"}
    if ortho:
        union_o = sum(m["union_cells"] for m in ortho)
        out["coverage"]["orthophoto"] = sum(m["union_coloured"] for m in ortho) / union_o if union_o else None
        out["orthophoto_coverage"] = out["coverage"]["orthophoto"]
    out["coverage"]["note"] = ("share of the union of the registered photos' footprints (each image's border cast "
                               "onto the ground below it) that has a height (DSM) and a colour (orthophoto)")
    return out
