"""The mapping products as files a GIS opens: Cloud-Optimized GeoTIFFs (rasterio), LAZ (laspy with
lazrs) and PNG previews.

- ``orthophoto.tif``: RGBA uint8, alpha 0 outside the flight, DEFLATE, 512 px tiles, overviews (COG).
- ``dsm.tif``: float32 heights in metres (the world frame's z), nodata :data:`DSM_NODATA`, same grid.
- ``points.laz``: LAS 1.4 point format 7 (x, y, z in millimetres, 16-bit RGB), CRS as WKT.

Without a CRS (a flight without GPS) the files carry no CRS and coordinates in the arbitrary frame.
rasterio, laspy and pyproj are imported here, inside the functions: the service never pays for them
on start-up (rasterio alone takes ~0.25 s to import).
"""
from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Iterable

import cv2
import numpy as np

from workers.common.images import encode_png

from .surface import Grid

DSM_NODATA = -9999.0
_PREVIEW_SIDE = 1024
_BLOCK = 512


def crs_of(epsg: int | None):
    """rasterio's CRS of an EPSG code (None: none)."""
    from rasterio.crs import CRS

    return CRS.from_epsg(epsg) if epsg is not None else None


def transform_of(grid: Grid, origin: np.ndarray):
    """rasterio's affine transform of ``grid`` in a world frame offset by ``origin`` (3,)."""
    from rasterio.transform import Affine

    a, b, c, d, e, f = grid.affine()
    return Affine(a, b, c + float(origin[0]), d, e, f + float(origin[1]))


def write_cog(path: Path, grid: Grid, count: int, dtype: str,
              windows: Iterable[tuple[tuple[int, int, int, int], np.ndarray]], epsg: int | None, origin: np.ndarray,
              nodata: float | None = None, colorinterp=None, predictor: int | None = None) -> None:
    """A Cloud-Optimized GeoTIFF at ``path`` of ``count`` bands of ``dtype`` on ``grid`` (offset by ``origin``, CRS
    ``epsg``), written from ``windows`` ((r0, r1, c0, c1) end exclusive, (bands, h, w) array) one at a time into a
    tiled GeoTIFF (BigTIFF when it must be), then copied by GDAL's COG driver: DEFLATE, 512 px blocks, overviews by
    averaging. Cells no window writes stay 0 (``nodata`` names the bands' nodata value)."""
    import rasterio
    from rasterio.shutil import copy as rio_copy
    from rasterio.windows import Window

    scratch = Path(tempfile.mkdtemp(prefix="sweepcast-cog-"))
    extra = {"predictor": predictor} if predictor else {}
    try:
        tmp = scratch / "tiled.tif"
        with rasterio.open(tmp, "w", driver="GTiff", width=grid.width, height=grid.height, count=count, dtype=dtype,
                           crs=crs_of(epsg), transform=transform_of(grid, origin), nodata=nodata, tiled=True,
                           blockxsize=_BLOCK, blockysize=_BLOCK, compress="deflate", bigtiff="IF_SAFER",
                           **extra) as dst:
            for (r0, r1, c0, c1), data in windows:
                dst.write(data, window=Window(c0, r0, c1 - c0, r1 - r0))
            if colorinterp is not None:
                dst.colorinterp = colorinterp
        rio_copy(tmp, path, driver="COG", compress="deflate", blocksize=_BLOCK, overview_resampling="average",
                 bigtiff="IF_SAFER", **extra)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def write_laz(path: Path, chunks: Iterable[tuple[np.ndarray, np.ndarray]], epsg: int | None, origin: np.ndarray,
              low: np.ndarray) -> int:
    """points.laz from chunks of (points (n, 3) in the world frame, colours (n, 3) uint8 BGR), chunk after chunk:
    LAS 1.4 point format 7, ``points + origin`` in millimetre steps from offsets at ``low + origin`` (``low`` (3,)
    the cloud's least x, y, z), 16-bit colours, CRS ``epsg`` (None: none). Returns how many points it wrote."""
    import laspy

    header = laspy.LasHeader(point_format=7, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.floor(np.asarray(low, np.float64) + np.asarray(origin, np.float64))
    if epsg is not None:
        from pyproj import CRS

        header.add_crs(CRS.from_epsg(epsg))
    total = 0
    with laspy.open(str(path), mode="w", header=header, do_compress=True, laz_backend=laspy.LazBackend.Lazrs) as out:
        for pts, cols in chunks:
            if len(pts) == 0:
                continue
            rec = laspy.ScaleAwarePointRecord.zeros(len(pts), header=header)
            xyz = np.asarray(pts, np.float64) + np.asarray(origin, np.float64)
            rec.x, rec.y, rec.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
            c = np.asarray(cols, np.uint16) * 257  # 8-bit -> LAS's 16-bit colour
            rec.red, rec.green, rec.blue = c[:, 2], c[:, 1], c[:, 0]
            out.write_points(rec)
            total += len(pts)
    return total


def preview_size(h: int, w: int, side: int = _PREVIEW_SIDE) -> tuple[int, int]:
    """(width, height) of a preview of an h x w raster: at most ``side`` pixels along its longer side."""
    s = min(1.0, side / max(h, w))
    return max(1, int(round(w * s))), max(1, int(round(h * s)))


def orthophoto_png(rgba: np.ndarray, side: int = _PREVIEW_SIDE) -> bytes:
    """A PNG preview (at most ``side`` px) of an RGBA orthophoto (H, W, 4) uint8, transparent outside."""
    small = cv2.resize(rgba, preview_size(*rgba.shape[:2], side), interpolation=cv2.INTER_AREA)
    return encode_png(cv2.cvtColor(small, cv2.COLOR_RGBA2BGRA), level=None)


def dsm_png(dsm: np.ndarray, side: int = _PREVIEW_SIDE) -> bytes:
    """A PNG preview of a DSM (H, W): heights coloured from the 2nd to the 98th percentile (turbo) and
    hill-shaded, transparent where NaN."""
    h, w = dsm.shape
    size = preview_size(h, w, side)
    known = np.isfinite(dsm)
    z = cv2.resize(np.where(known, dsm, np.nanmedian(dsm) if known.any() else 0).astype(np.float32), size,
                   interpolation=cv2.INTER_AREA)
    valid = cv2.resize(known.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST).astype(bool)
    lo, hi = (np.percentile(z[valid], [2, 98]) if valid.any() else (0.0, 1.0))
    level = np.clip((z - lo) / max(hi - lo, 1e-9) * 255, 0, 255).astype(np.uint8)
    colour = cv2.applyColorMap(level, cv2.COLORMAP_TURBO).astype(np.float32)
    gy, gx = np.gradient(z)
    scale = (hi - lo) / 50 if hi > lo else 1.0  # relief of 2 % of the range per pixel reads as a strong slope
    shade = np.clip(0.75 + 0.25 * (-gx - gy) / max(scale, 1e-9), 0.4, 1.0)
    bgra = np.dstack([np.clip(colour * shade[..., None], 0, 255).astype(np.uint8), valid.astype(np.uint8) * 255])
    return encode_png(bgra, level=None)
