"""The ground a survey covers: each registered photo's footprint, the grids of the DSM and the orthophoto over
their union, the ground tiles the map stages work in, and how much of that union a product covers.

- **Footprint**: the image's border (through the lens) cast onto the level ground below the camera (the median
  height of the sparse points the photo sees), a polygon in the world's x, y. A ray that would meet the ground
  farther than :data:`FOOTPRINT_REACH` camera heights away (an oblique video frame) is cut there.
- **Grids**: the orthophoto's cell is the photos' own ground sampling distance (a native pixel straight below the
  camera at the median depth) unless ``gsd_cm`` asks for another; the DSM's is the depth maps' own (the working
  resolution times ``dense_scale``), a whole multiple of the orthophoto's, never finer. Both start at the same
  corner, on whole DSM cells, over the union of the footprints.
- **Tiles**: squares of the DSM grid as large as a tile's task may hold (at most :data:`MAX_ORTHO_TILE` orthophoto
  cells along a side and :data:`MAX_TILE_PHOTOS` photos meeting it, so that its memory stays bounded whatever the
  survey's size), but at least as many as the fan-out runs at once, so that every CPU has one: each tile reads and
  fuses again the depth maps that reach into it, so smaller tiles than that cost more for nothing (a 28-still survey
  in six tiles a footprint wide spent 8.3 s on its surface and orthophoto tiles, against 5.3 s in one).
- **Coverage**: the share of the union of the footprints (rasterised on a tile's grid) where the DSM has a height
  and the orthophoto a colour.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from ..geometry import camera_centre
from ..reconstruction import SparseModel
from ..surface import Grid

FOOTPRINT_REACH = 4.0
"""Farthest a footprint reaches from the point below the camera, in camera heights above the ground."""
MAX_ORTHO_TILE = 2048
"""Most orthophoto cells along a tile's side (a 2048 x 2048 tile's arrays, RGBA and scores, stay near 100 MB)."""
MIN_DSM_TILE = 128
MAX_TILE_PHOTOS = 60
"""Most photos whose footprints (bounding boxes) meet one tile: a surface task holds their depth maps, and their
neighbours', at once. The footprint-wide tiles the scale runs' memory was measured with met up to 60 on the 75 / 65 %
overlap surveys of 448 and 1,008 stills; a small survey's whole map meets fewer, and is one tile a CPU."""
FILL_SHIFT = 4
"""Sub-cell precision of the rasterised footprints (cv2.fillPoly's ``shift``: 1/16 cell)."""


def frame_ground_heights(model: SparseModel) -> np.ndarray:
    """(F,) the ground height below each frame: the median height of the sparse points it observes (all points'
    median where it observes fewer than 10; NaN for unregistered frames)."""
    out = np.full(len(model.registered), np.nan)
    overall = float(np.median(model.points[:, 2])) if len(model.points) else 0.0
    seen = model.points_by_frame()
    for f in np.flatnonzero(model.registered):
        pts = seen[f]
        out[f] = float(np.median(model.points[pts, 2])) if len(pts) >= 10 else overall
    return out


def image_border(width: int, height: int, per_side: int) -> np.ndarray:
    """(4 per_side, 2) pixel x, y around an image's border, clockwise from its top-left corner, ``per_side`` a side."""
    s = np.linspace(0.0, 1.0, per_side, endpoint=False)
    w, h = width - 1, height - 1
    return np.concatenate([np.column_stack([s * w, np.zeros_like(s)]),
                           np.column_stack([np.full_like(s, w), s * h]),
                           np.column_stack([(1 - s) * w, np.full_like(s, h)]),
                           np.column_stack([np.zeros_like(s), (1 - s) * h])])


def footprints(model: SparseModel, per_side: int = 8, heights: np.ndarray | None = None) -> dict[int, np.ndarray]:
    """Frame -> its footprint (K, 2) world x, y (module docstring) for every registered frame of a model in a level
    world frame (z up). Pixels are the working resolution's; a self-calibrated lens's border is undistorted first.
    ``heights``: each frame's ground height when already known (:func:`frame_ground_heights`)."""
    heights = frame_ground_heights(model) if heights is None else heights
    border = image_border(model.width, model.height, per_side)
    if model.lens is not None:
        border = model.lens.undistort(border)
    rays_cam = np.column_stack([border, np.ones(len(border))]) @ np.linalg.inv(model.K).T
    out = {}
    for f in np.flatnonzero(model.registered):
        C = camera_centre(model.R[f], model.t[f])
        height = C[2] - heights[f]
        if not height > 0:
            continue
        d = rays_cam @ model.R[f]  # world directions
        down = -d[:, 2]
        reach = FOOTPRINT_REACH * height
        t = np.where(down > 1e-9, height / np.maximum(down, 1e-9), np.inf)
        horizontal = np.linalg.norm(d[:, :2], axis=1)
        t = np.minimum(t, reach / np.maximum(horizontal, 1e-9))
        out[int(f)] = C[:2] + t[:, None] * d[:, :2]
    return out


def flight_gsd(model: SparseModel) -> float:
    """The working images' ground sampling distance (world units per working pixel): the median over registered
    frames of the median depth of the sparse points each sees, over the focal length. Raises ValueError when no
    registered frame sees ten points."""
    depths = []
    seen = model.points_by_frame()
    for f in np.flatnonzero(model.registered):
        pts = model.points[seen[f]]
        if len(pts) >= 10:
            z = pts @ model.R[f][2] + model.t[f][2]
            if (z > 0).any():
                depths.append(float(np.median(z[z > 0])))
    if not depths:
        raise ValueError("no registered frame sees the sparse points: no ground sampling distance")
    return float(np.median(depths)) / float(model.K[0, 0])


@dataclass(frozen=True)
class GroundPlan:
    """The grids and tiles of a map (module docstring). ``dsm`` the DSM's grid, ``factor`` orthophoto cells per DSM
    cell along a side, ``tile`` DSM cells along a tile's side; ``gsd_reason`` in words; ``photo_gsd``,
    ``dense_gsd`` the photos' own and the depth maps' ground sampling distances."""

    dsm: Grid
    factor: int
    tile: int
    photo_gsd: float
    dense_gsd: float
    gsd_reason: str

    @property
    def ortho(self) -> Grid:
        """The orthophoto's grid: the DSM's corner, ``factor`` times finer."""
        g = self.dsm
        return Grid(g.x0, g.y0, g.gsd / self.factor, g.width * self.factor, g.height * self.factor)

    def tiles(self) -> list[tuple[int, int]]:
        """Every tile's (row, column) in the tile layout, row by row."""
        return [(r, c) for r in range(math.ceil(self.dsm.height / self.tile))
                for c in range(math.ceil(self.dsm.width / self.tile))]

    def window(self, tile: tuple[int, int], margin: int = 0) -> tuple[int, int, int, int]:
        """DSM rows and columns (r0, r1, c0, c1), end exclusive, of a tile widened by ``margin`` cells, clipped."""
        r, c = tile
        t = self.tile
        return (max(0, r * t - margin), min(self.dsm.height, (r + 1) * t + margin),
                max(0, c * t - margin), min(self.dsm.width, (c + 1) * t + margin))

    def bounds(self, tile: tuple[int, int], margin_m: float = 0.0) -> tuple[float, float, float, float]:
        """World (x0, x1, y0, y1) of a tile widened by ``margin_m``."""
        r0, r1, c0, c1 = self.window(tile)
        g = self.dsm
        return (g.x0 + c0 * g.gsd - margin_m, g.x0 + c1 * g.gsd + margin_m,
                g.y0 - r1 * g.gsd - margin_m, g.y0 - r0 * g.gsd + margin_m)

    def report(self) -> dict:
        o = self.ortho
        return {"orthophoto_gsd": o.gsd, "dsm_gsd": self.dsm.gsd, "photo_gsd": self.photo_gsd,
                "depth_map_gsd": self.dense_gsd, "gsd_reason": self.gsd_reason,
                "orthophoto_size": [o.width, o.height], "dsm_size": [self.dsm.width, self.dsm.height],
                "tile_dsm_cells": self.tile, "tiles": len(self.tiles())}


def sub_grid(grid: Grid, window: tuple[int, int, int, int]) -> Grid:
    """The part of ``grid`` in rows r0:r1, columns c0:c1 as a grid of its own."""
    r0, r1, c0, c1 = window
    return Grid(grid.x0 + c0 * grid.gsd, grid.y0 - r0 * grid.gsd, grid.gsd, c1 - c0, r1 - r0)


def plan_ground(model: SparseModel, prints: dict[int, np.ndarray], gsd: float | None, dense_scale: float,
                unit: str, max_pixels: int, min_tiles: int = 1) -> GroundPlan:
    """The :class:`GroundPlan` of a model in a level world frame with footprints ``prints`` (see
    :func:`footprints`); ``gsd`` the orthophoto's cell asked for (world units; None: the photos' own); ``unit``
    names the world units in messages; ``min_tiles`` how many tiles the map should have at least (the tasks the
    fan-out runs at once; fewer where tiles would be smaller than :data:`MIN_DSM_TILE`). Raises ValueError when there
    is no footprint, or when the orthophoto would have more than ``max_pixels`` cells (the message says which cell
    size would fit)."""
    if not prints:
        raise ValueError("no registered frame has a footprint on the ground")
    working = flight_gsd(model)
    photo = working * model.scale
    dense = working / dense_scale
    if gsd is None:
        cell, reason = photo, (f"the photos' own: a native pixel straight below the camera at the median depth "
                               f"({photo * 100:.2f} cm)" if unit == "m" else "the photos' own (a native pixel straight "
                               "below the camera at the median depth)")
    else:
        cell = float(gsd)
        rel = "coarser than" if cell > photo * 1.001 else "finer than" if cell < photo * 0.999 else "equal to"
        reason = (f"asked (gsd_cm), {rel} the photos' own {photo * 100:.2f} cm" + (
            ": the orthophoto interpolates between their pixels" if rel == "finer than" else "")
            if unit == "m" else f"asked, {rel} the photos' own")
    factor = max(1, int(round(dense / cell)))
    dsm_cell = cell * factor
    pts = np.concatenate(list(prints.values()))
    lo, hi = pts.min(axis=0) - 2 * dsm_cell, pts.max(axis=0) + 2 * dsm_cell
    x0 = math.floor(lo[0] / dsm_cell) * dsm_cell
    y0 = math.ceil(hi[1] / dsm_cell) * dsm_cell
    width = max(1, int(math.ceil((hi[0] - x0) / dsm_cell)))
    height = max(1, int(math.ceil((y0 - lo[1]) / dsm_cell)))
    pixels = width * height * factor * factor
    if pixels > max_pixels:
        fit = cell * math.sqrt(pixels / max_pixels)
        raise ValueError(f"an orthophoto of {cell * 100:.2f} cm cells over this flight's {width * dsm_cell:.0f} x "
                         f"{height * dsm_cell:.0f} {unit} would have {pixels:,} pixels, more than the service's "
                         f"limit of {max_pixels:,} (SWEEPCAST_MAX_MAP_PIXELS): ask for gsd_cm {fit * 100:.1f} or more"
                         if unit == "m" else
                         f"the orthophoto would have {pixels:,} pixels, more than the service's limit of "
                         f"{max_pixels:,} (SWEEPCAST_MAX_MAP_PIXELS)")
    boxes = _cell_boxes(prints, float(x0), float(y0), dsm_cell)
    tile = tile_side(width, height, max(MIN_DSM_TILE, MAX_ORTHO_TILE // factor), min_tiles,
                     lambda side: most_photos_in_a_tile(boxes, width, height, side) <= MAX_TILE_PHOTOS)
    return GroundPlan(Grid(float(x0), float(y0), float(dsm_cell), width, height), factor, tile, photo, dense, reason)


def tile_side(width: int, height: int, largest: int, min_tiles: int,
              fits: Callable[[int], bool] = lambda side: True) -> int:
    """DSM cells along a tile's side for a ``width`` x ``height`` cell grid: the largest side up to ``largest`` that
    ``fits`` (a task's memory: :func:`most_photos_in_a_tile`) and cuts the grid into at least ``min_tiles`` tiles,
    but not below :data:`MIN_DSM_TILE` (a small map is fewer tiles)."""
    # the sides at which a tile count changes: either side of the grid cut into whole parts
    sides = sorted({math.ceil(n / k) for n in (width, height) for k in range(1, n + 1)}, reverse=True)
    for side in sides:
        if side > largest:
            continue
        if side <= MIN_DSM_TILE:
            break
        if math.ceil(width / side) * math.ceil(height / side) >= min_tiles and fits(side):
            return side
    return MIN_DSM_TILE


def _cell_boxes(prints: dict[int, np.ndarray], x0: float, y0: float, cell: float) -> np.ndarray:
    """(F, 4) each footprint's bounding box in cells of a grid with corner (x0, y0) and cell ``cell``: column
    from, column to, row from, row to (fractional, y down)."""
    out = np.empty((len(prints), 4))
    for i, p in enumerate(prints.values()):
        out[i] = ((p[:, 0].min() - x0) / cell, (p[:, 0].max() - x0) / cell,
                  (y0 - p[:, 1].max()) / cell, (y0 - p[:, 1].min()) / cell)
    return out


def most_photos_in_a_tile(boxes: np.ndarray, width: int, height: int, side: int) -> int:
    """The most photos whose footprint's bounding box (``boxes``: :func:`_cell_boxes`) meets one tile, with tiles
    of ``side`` cells over a ``width`` x ``height`` grid: what one surface task loads at least (their depth maps)."""
    cols, rows = math.ceil(width / side), math.ceil(height / side)
    c0, c1, r0, r1 = np.clip(np.floor(boxes / side).astype(np.int64), 0, [cols - 1, cols - 1, rows - 1, rows - 1]).T
    counts = np.zeros((rows + 1, cols + 1), np.int64)  # a 2D difference array: +1 on each box's tiles
    np.add.at(counts, (r0, c0), 1)
    np.add.at(counts, (r0, c1 + 1), -1)
    np.add.at(counts, (r1 + 1, c0), -1)
    np.add.at(counts, (r1 + 1, c1 + 1), 1)
    return int(counts.cumsum(axis=0).cumsum(axis=1).max()) if len(boxes) else 0


def footprint_mask(grid: Grid, polygons: list[np.ndarray]) -> np.ndarray:
    """(H, W) bool: the cells of ``grid`` whose centre lies in the union of ``polygons`` ((K, 2) world x, y each)."""
    mask = np.zeros((grid.height, grid.width), np.uint8)
    scale = 1 << FILL_SHIFT
    for poly in polygons:
        col = (poly[:, 0] - grid.x0) / grid.gsd - 0.5
        row = (grid.y0 - poly[:, 1]) / grid.gsd - 0.5
        pts = np.rint(np.column_stack([col, row]) * scale).astype(np.int64)
        if np.abs(pts).max() > 2**30:
            continue
        cv2.fillPoly(mask, [pts.astype(np.int32)], 1, lineType=cv2.LINE_8, shift=FILL_SHIFT)
    return mask.astype(bool)


def overlapping(prints: dict[int, np.ndarray], bounds: tuple[float, float, float, float]) -> list[int]:
    """Frames whose footprint's bounding box meets the world box (x0, x1, y0, y1)."""
    x0, x1, y0, y1 = bounds
    out = []
    for f, p in prints.items():
        lo, hi = p.min(axis=0), p.max(axis=0)
        if lo[0] <= x1 and hi[0] >= x0 and lo[1] <= y1 and hi[1] >= y0:
            out.append(f)
    return sorted(out)
