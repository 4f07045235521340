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

import io

import cv2
import numpy as np

from workers.common.images import encode_png

from .surface import Grid

DSM_NODATA = -9999.0
_PREVIEW_SIDE = 1024


def _crs(epsg: int | None):
    from rasterio.crs import CRS

    return CRS.from_epsg(epsg) if epsg is not None else None


def _transform(grid: Grid, origin: np.ndarray):
    from rasterio.transform import Affine

    a, b, c, d, e, f = grid.affine()
    return Affine(a, b, c + float(origin[0]), d, e, f + float(origin[1]))


def orthophoto_tif(rgba: np.ndarray, grid: Grid, epsg: int | None, origin: np.ndarray) -> bytes:
    """COG bytes of an RGBA orthophoto (H, W, 4) uint8 on ``grid`` (its frame offset by ``origin`` (3,):
    the UTM coordinates of the world frame's zero), in ``epsg`` (None: no CRS)."""
    from rasterio.enums import ColorInterp
    from rasterio.io import MemoryFile

    h, w = rgba.shape[:2]
    with MemoryFile() as mem:
        with mem.open(driver="COG", width=w, height=h, count=4, dtype="uint8", crs=_crs(epsg),
                      transform=_transform(grid, origin), compress="deflate", blocksize=512,
                      overview_resampling="average") as dst:
            dst.write(np.moveaxis(rgba, 2, 0))
            dst.colorinterp = [ColorInterp.red, ColorInterp.green, ColorInterp.blue, ColorInterp.alpha]
        return mem.read()


def dsm_tif(dsm: np.ndarray, grid: Grid, epsg: int | None, origin: np.ndarray) -> bytes:
    """COG bytes of a DSM (H, W) float32 (NaN: nodata, written as :data:`DSM_NODATA`) on ``grid``, heights
    plus ``origin[2]``."""
    from rasterio.io import MemoryFile

    h, w = dsm.shape
    data = np.where(np.isfinite(dsm), dsm + float(origin[2]), DSM_NODATA).astype(np.float32)
    with MemoryFile() as mem:
        with mem.open(driver="COG", width=w, height=h, count=1, dtype="float32", crs=_crs(epsg),
                      transform=_transform(grid, origin), compress="deflate", predictor=3, blocksize=512,
                      nodata=DSM_NODATA, overview_resampling="average") as dst:
            dst.write(data, 1)
        return mem.read()


def laz_bytes(points: np.ndarray, colors_bgr: np.ndarray, epsg: int | None, origin: np.ndarray) -> bytes:
    """LAZ bytes of points (N, 3) in the world frame (written as ``points + origin``, millimetre steps)
    with colours (N, 3) uint8 BGR, CRS ``epsg`` (None: none)."""
    import laspy

    xyz = np.asarray(points, np.float64) + np.asarray(origin, np.float64)
    header = laspy.LasHeader(point_format=7, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.floor(xyz.min(axis=0)) if len(xyz) else np.zeros(3)
    if epsg is not None:
        from pyproj import CRS

        header.add_crs(CRS.from_epsg(epsg))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    colors = np.asarray(colors_bgr, np.uint16) * 257  # 8-bit -> LAS's 16-bit colour
    las.red, las.green, las.blue = colors[:, 2], colors[:, 1], colors[:, 0]
    buf = io.BytesIO()
    las.write(buf, do_compress=True, laz_backend=laspy.LazBackend.Lazrs)
    return buf.getvalue()


def _fit(h: int, w: int, side: int) -> tuple[int, int]:
    s = min(1.0, side / max(h, w))
    return max(1, int(round(w * s))), max(1, int(round(h * s)))


def orthophoto_png(rgba: np.ndarray, side: int = _PREVIEW_SIDE) -> bytes:
    """A PNG preview (at most ``side`` px) of an RGBA orthophoto (H, W, 4) uint8, transparent outside."""
    small = cv2.resize(rgba, _fit(*rgba.shape[:2], side), interpolation=cv2.INTER_AREA)
    return encode_png(cv2.cvtColor(small, cv2.COLOR_RGBA2BGRA), level=None)


def dsm_png(dsm: np.ndarray, side: int = _PREVIEW_SIDE) -> bytes:
    """A PNG preview of a DSM (H, W): heights coloured from the 2nd to the 98th percentile (turbo) and
    hill-shaded, transparent where NaN."""
    h, w = dsm.shape
    size = _fit(h, w, side)
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
