"""The map's files written from the tiles in the job's work area, a tile at a time, so the job's own process never
holds a whole survey: the GeoTIFFs window by window (:func:`workers.drone.mapfiles.write_cog`), the dense PLY
tile by tile, the depth maps' zip file by file, the PNG previews from each tile shrunk onto the preview's canvas.

:class:`MapTiles` also reads the products back whole (:meth:`MapTiles.orthophoto`, :meth:`MapTiles.dsm`): for
tests and benchmarks that compare them with a truth.
"""
from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from workers.workarea import WorkArea

from ..export import PLY_DENSE_FIELDS, ply_header, ply_rows
from ..mapfiles import DSM_NODATA, dsm_png, orthophoto_png, preview_size, write_cog
from ..surface import Grid
from .ground import GroundPlan
from .surface import tile_name


@dataclass
class MapTiles:
    """The tiles of a job's map in its work area: the ground plan and the tiles that hold points and rasters."""

    work: WorkArea
    ground: GroundPlan
    tiles: list[tuple[int, int]]

    def point_chunks(self) -> Iterator[dict[str, np.ndarray]]:
        """Each tile's points (``points`` (n, 3) float32 world, ``colors`` (n, 3) uint8 BGR, ``normals`` (n, 3)
        float32, ``views`` (n,) uint8), tile after tile."""
        for t in self.tiles:
            yield self.work.get_arrays(tile_name("points", t) + ".npz")

    def sample(self) -> tuple[np.ndarray, np.ndarray]:
        """The preview's sample of the dense points (N, 3) float32 and their colours (N, 3) uint8 BGR."""
        parts = [self.work.get_arrays(tile_name("sample", t) + ".npz") for t in self.tiles]
        if not parts:
            return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8)
        return np.concatenate([p["points"] for p in parts]), np.concatenate([p["colors"] for p in parts])

    def _raster(self, kind: str, key: str, fine: bool, fill, dtype, channels: int) -> np.ndarray:
        g = self.ground.ortho if fine else self.ground.dsm
        f = self.ground.factor if fine else 1
        out = np.full((g.height, g.width, channels) if channels > 1 else (g.height, g.width), fill, dtype)
        for t in self.tiles:
            r0, r1, c0, c1 = self.ground.window(t)
            out[r0 * f:r1 * f, c0 * f:c1 * f] = self.work.get_arrays(tile_name(kind, t) + ".npz")[key]
        return out

    def dsm(self) -> np.ndarray:
        """The whole DSM (H, W) float32 on ``ground.dsm`` (NaN: nodata)."""
        return self._raster("dsm", "dsm", False, np.nan, np.float32, 1)

    def orthophoto(self) -> np.ndarray:
        """The whole orthophoto (H, W, 4) uint8 RGBA on ``ground.ortho``."""
        return self._raster("ortho", "rgba", True, 0, np.uint8, 4)

    def sources(self) -> np.ndarray:
        """The model frame each orthophoto cell came from (H, W) int32 (-1: none)."""
        return self._raster("ortho", "source", True, -1, np.int32, 1)


def write_orthophoto(maps: MapTiles, tif: Path, png: Path, epsg: int | None, origin: np.ndarray) -> None:
    """orthophoto.tif (COG, RGBA) and its PNG preview, from the tiles."""
    from rasterio.enums import ColorInterp

    g, f = maps.ground.ortho, maps.ground.factor
    canvas, s = _canvas(g, 4)

    def windows():
        for t in maps.tiles:
            r0, r1, c0, c1 = maps.ground.window(t)
            rgba = maps.work.get_arrays(tile_name("ortho", t) + ".npz")["rgba"]
            _shrink_onto(canvas, s, rgba, r0 * f, c0 * f)
            yield (r0 * f, r1 * f, c0 * f, c1 * f), np.moveaxis(rgba, 2, 0)

    write_cog(tif, g, 4, "uint8", windows(), epsg, origin,
               colorinterp=[ColorInterp.red, ColorInterp.green, ColorInterp.blue, ColorInterp.alpha])
    png.write_bytes(orthophoto_png(canvas))


def write_dsm(maps: MapTiles, tif: Path, png: Path, epsg: int | None, origin: np.ndarray) -> None:
    """dsm.tif (COG, float32 heights plus ``origin[2]``, nodata :data:`DSM_NODATA`) and its PNG preview."""
    g = maps.ground.dsm
    canvas, s = _canvas(g, 1, np.nan, np.float32)

    def windows():
        for t in maps.tiles:
            r0, r1, c0, c1 = maps.ground.window(t)
            dsm = maps.work.get_arrays(tile_name("dsm", t) + ".npz")["dsm"]
            _shrink_onto(canvas, s, dsm, r0, c0)
            data = np.where(np.isfinite(dsm), dsm + float(origin[2]), DSM_NODATA).astype(np.float32)
            yield (r0, r1, c0, c1), data[None]

    write_cog(tif, g, 1, "float32", windows(), epsg, origin, nodata=DSM_NODATA, predictor=3)
    png.write_bytes(dsm_png(canvas))


def _canvas(grid: Grid, channels: int, fill=0, dtype=np.uint8) -> tuple[np.ndarray, float]:
    """An empty preview canvas for a raster on ``grid`` (at most the previews' side) and its scale."""
    w, h = preview_size(grid.height, grid.width)
    shape = (h, w, channels) if channels > 1 else (h, w)
    return np.full(shape, fill, dtype), w / grid.width


def _shrink_onto(canvas: np.ndarray, s: float, tile: np.ndarray, r0: int, c0: int) -> None:
    """Put ``tile`` (its top-left at raster row r0, column c0) onto the preview canvas shrunk by ``s``
    (INTER_AREA; a float tile's NaN cells stay NaN where most of the shrunk cell is NaN)."""
    h, w = tile.shape[:2]
    y0, x0 = int(round(r0 * s)), int(round(c0 * s))
    y1, x1 = min(canvas.shape[0], int(round((r0 + h) * s))), min(canvas.shape[1], int(round((c0 + w) * s)))
    if y1 <= y0 or x1 <= x0:
        return
    if tile.dtype == np.float32:
        known = np.isfinite(tile)
        small = cv2.resize(np.where(known, tile, 0).astype(np.float32), (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
        share = cv2.resize(known.astype(np.float32), (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
        canvas[y0:y1, x0:x1] = np.where(share >= 0.5, small / np.maximum(share, 1e-6), np.nan)
    else:
        canvas[y0:y1, x0:x1] = cv2.resize(tile, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)


def write_dense_ply(maps: MapTiles, path: Path, total: int) -> None:
    """dense.ply (binary, x y z, normals, colours, views) from the tiles' points, ``total`` of them in all."""
    with open(path, "wb") as f:
        f.write(ply_header(total, PLY_DENSE_FIELDS, "sweepcast dense reconstruction"))
        for c in maps.point_chunks():
            f.write(ply_rows(c["points"], c["colors"], c["normals"], c["views"]))


def write_depth_zip(work: WorkArea, items: list[tuple[str, str]], path: Path) -> None:
    """depth.zip: ``items`` (work-area name of a depth PNG, its name in the zip), stored (PNG is compressed)."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
        for name, arcname in items:
            zf.writestr(arcname, work.get(name))
