"""The sweep's work items: tiles of the reference, each with the planes it searches (all of them, or those
a coarse search at half resolution leaves open)."""
from __future__ import annotations

import cv2
import numpy as np


def sweep_tiles(h: int, w: int, planes: int, windows: tuple[np.ndarray, np.ndarray] | None,
                tile: tuple[int, int] = (32, 128), spread: float = 2.0) -> np.ndarray:
    """The work items of :func:`.sweep.zncc_sweep`: (T, 6) int64 rows (y0, y1, x0, x1, j0, j1), tiles of at most
    ``tile`` (rows, columns) covering the h x w image, each with the planes its pixels' windows need: all
    ``planes`` when windows is None, else from the ``spread`` percentile of their lo to the ``100 - spread``
    percentile of their hi (pixels with lo > hi left out: a few stray windows do not widen a whole tile;
    0 takes the least and greatest); tiles that need none are left out."""
    th, tw = max(1, int(tile[0])), max(1, int(tile[1]))
    rows = []
    for y0 in range(0, h, th):
        y1 = min(h, y0 + th)
        for x0 in range(0, w, tw):
            x1 = min(w, x0 + tw)
            if windows is None:
                rows.append((y0, y1, x0, x1, 0, planes - 1))
                continue
            lo = windows[0][y0:y1, x0:x1]
            hi = windows[1][y0:y1, x0:x1]
            ok = lo <= hi
            if not ok.any():
                continue
            j0 = int(np.floor(np.percentile(lo[ok], spread)))
            j1 = int(np.ceil(np.percentile(hi[ok], 100 - spread)))
            rows.append((y0, y1, x0, x1, max(0, j0), min(planes - 1, j1)))
    return np.asarray(rows, np.int64).reshape(-1, 6)


def tile_map(tiles: np.ndarray, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel first and last plane searched, (h, w) int32 each, from :func:`sweep_tiles` rows (-1 where
    no tile covers a pixel)."""
    j0 = np.full((h, w), -1, np.int32)
    j1 = np.full((h, w), -1, np.int32)
    for y0, y1, x0, x1, a, b in tiles:
        j0[y0:y1, x0:x1] = a
        j1[y0:y1, x0:x1] = b
    return j0, j1


def coarse_windows(best_coarse: np.ndarray, value_coarse: np.ndarray, h: int, w: int, planes: int, margin: int,
                   max_cost: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel plane windows (lo, hi) (h, w) int32 for the full-resolution search from a half-resolution
    one (best_coarse (hc, wc) int32, -1 = none; value_coarse (hc, wc) float32 its cost): the least and
    greatest confident winner (cost <= ``max_cost``) of the 3 x 3 coarse pixels around, widened by
    ``margin`` planes; lo > hi (no window) where none of them is confident. A tile with no window at all
    searches every plane (:func:`.depth.depth_map`)."""
    b = np.where((best_coarse >= 0) & (value_coarse <= max_cost), best_coarse, -1).astype(np.int32)
    kernel = np.ones((3, 3), np.uint8)
    big = planes + margin + 1
    lo_c = cv2.erode(np.where(b >= 0, b, big).astype(np.float32), kernel).astype(np.int32)
    hi_c = cv2.dilate(np.where(b >= 0, b, -1).astype(np.float32), kernel).astype(np.int32)
    none = hi_c < 0
    lo_c = np.where(none, 1, lo_c - margin)
    hi_c = np.where(none, 0, hi_c + margin)
    lo = cv2.resize(lo_c.astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST).astype(np.int32)
    hi = cv2.resize(hi_c.astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST).astype(np.int32)
    return np.clip(lo, 0, planes), np.clip(hi, 0, planes - 1)
