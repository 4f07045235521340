"""Dense reconstruction from calibrated, posed images: a depth map per reference frame by plane sweep,
geometric consistency across neighbours, fusion into one coloured point cloud with normals.

Pipeline (:func:`densify` runs it on a :class:`~workers.drone.reconstruction.SparseModel`):

1. **Neighbours** (:func:`select_neighbours`): for a reference frame, every other frame is scored by the
   sparse points both see, each weighted by the triangulation angle between the two rays (a Gaussian
   around ``best_deg`` = 5 deg: too small a baseline gives no depth resolution, too large one no matching);
   the best ``neighbours`` frames with a positive score are its neighbours.
2. **Depth map** (:func:`depth_map`): a sweep of ``planes`` fronto-parallel planes of the reference,
   uniform in inverse depth between the depths of the sparse points the frame sees (widened by a margin).
   At each plane every neighbour is resampled into the reference (bilinear; the plane-induced homography
   in the renderer's form ``Q + s B e3^T``, :mod:`workers.sweep.kernels`) and compared with the reference
   by ZNCC over a (2 radius + 1)^2 window (:func:`workers.sweep.costs.zncc_cost`: a gain or offset
   between frames, the exposure changes of real video, does not change it); the cost of a plane is the
   mean of the best ``k`` neighbours' ``1 - ZNCC`` (:func:`workers.sweep.costs.best_k_mean`: occluded
   neighbours are left out), the winner per pixel and a parabola through its neighbours' costs give a
   sub-plane inverse depth (:func:`workers.sweep.costs.winner`). One fused, compiled kernel does all of
   this per tile of the reference and never holds the (h, w, planes) volume unless asked to (semi-global
   aggregation, :func:`workers.sweep.costs.semi_global`, needs it). Coarse to fine (the job's default):
   every other plane at half resolution first, then at full resolution each tile sweeps only the planes
   near the sure coarse depths. A pixel keeps its depth where the winning cost is at most ``max_cost`` and
   its window has texture (``min_std``).
3. **Consistency** (:func:`consistency`): a reference pixel's 3D point is projected into each
   neighbour's depth map; the neighbour agrees when its depth there, projected back, lands within
   ``max_reprojection_px`` of the pixel and within ``max_depth_ratio`` of the depth.
4. **Fusion** (:func:`fuse`): pixels that at least ``min_views`` frames (the reference included) agree on
   become one point each: the mean of the agreeing frames' points and colours, a normal from the
   reference depth map's gradient (camera space, turned towards the camera). Pixels of neighbours that
   took part are marked used, so later references do not add the same surface again.

Conventions as everywhere (:mod:`workers.camera`): world-to-camera ``x_cam = R X + t``, OpenCV axes,
pixel (0, 0) at the centre of the top-left pixel; depth is z along the optical axis in the model's units.
"""
from __future__ import annotations

import io
import math
import time
import zipfile
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import cv2
import numpy as np
from numba import njit, prange

from workers.sweep import costs
from workers.sweep.costs import parabola_vertex

ProgressFn = Callable[[float, str], None]

DEPTH_PNG_LEVELS = 65535  # a depth map PNG stores round(depth / scale), 0 = no depth
_FM = {"nsz", "contract", "arcp", "reassoc"}  # never "nnan"/"ninf": inf marks a pixel without a cost


# ---------------------------------------------------------------------------------------------
# Views and geometry
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class View:
    """One posed image: ``image`` (h, w, 3) uint8 BGR, ``K`` (3, 3), world-to-camera ``R`` (3, 3) and
    ``t`` (3,) float64, ``name``."""

    name: str
    image: np.ndarray
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.image.shape[1], self.image.shape[0]

    @property
    def center(self) -> np.ndarray:
        """Camera centre (3,) float64 in world coordinates."""
        return -self.R.T @ self.t

    def gray(self) -> np.ndarray:
        """(h, w) float32 grey levels 0..255."""
        return cv2.cvtColor(self.image, cv2.COLOR_BGR2GRAY).astype(np.float32)

    def scaled(self, factor: float) -> "View":
        """The view with its image resized by ``factor`` (INTER_AREA) and K to match (pixel centres kept)."""
        if factor == 1.0:
            return self
        w, h = self.size
        size = (max(1, int(round(w * factor))), max(1, int(round(h * factor))))
        sx, sy = size[0] / w, size[1] / h
        S = np.array([[sx, 0, 0.5 * sx - 0.5], [0, sy, 0.5 * sy - 0.5], [0, 0, 1]])
        img = cv2.resize(self.image, size, interpolation=cv2.INTER_AREA)
        return View(self.name, img, S @ self.K, self.R, self.t)


def sweep_geometry(ref: View, others: Sequence[View]) -> tuple[np.ndarray, np.ndarray]:
    """The plane-induced homographies of ``others`` seen from ``ref``: Q (N, 3, 3), B (N, 3) float64.

    Reference pixel (x, y) at inverse depth s (1/z, z along the reference's optical axis) appears in view
    i at the homogeneous pixel ``Q[i] @ (x, y, 1) + s * B[i]``; ``Q[i] = K_i R_i R_ref^T K_ref^-1`` and
    ``B[i] = K_i (R_i C_ref + t_i)`` (the renderer's form, :mod:`workers.sweep.kernels`)."""
    G = ref.R.T @ np.linalg.inv(ref.K)
    C = ref.center
    Q = np.stack([o.K @ o.R @ G for o in others]) if others else np.zeros((0, 3, 3))
    B = np.stack([o.K @ (o.R @ C + o.t) for o in others]) if others else np.zeros((0, 3))
    return np.ascontiguousarray(Q, np.float64), np.ascontiguousarray(B, np.float64)


def plane_samples(image: np.ndarray, Q: np.ndarray, B: np.ndarray, s: float, h: int, w: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """One view's grey image (H, W) float32 resampled into an h x w reference for the plane at inverse
    depth ``s``: (h, w) float32 samples (bilinear, positions clamped to the image) and (h, w) bool, True
    where the point is in front of the view and inside its image. Plain numpy: the definition the
    compiled sweep reproduces (used by tests and by the colour lookups of the fusion)."""
    Hn, Wn = image.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    hx = Q[0, 0] * xs + Q[0, 1] * ys + Q[0, 2] + s * B[0]
    hy = Q[1, 0] * xs + Q[1, 1] * ys + Q[1, 2] + s * B[1]
    hz = Q[2, 0] * xs + Q[2, 1] * ys + Q[2, 2] + s * B[2]
    front = hz > 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(front, hx / np.where(front, hz, 1.0), 0.0)
        v = np.where(front, hy / np.where(front, hz, 1.0), 0.0)
    ok = front & (u >= 0) & (u <= Wn - 1) & (v >= 0) & (v <= Hn - 1)
    uc = np.clip(u, 0, Wn - 1)
    vc = np.clip(v, 0, Hn - 1)
    ix = np.minimum(uc.astype(np.int64), max(Wn - 2, 0))
    iy = np.minimum(vc.astype(np.int64), max(Hn - 2, 0))
    fx, fy = uc - ix, vc - iy
    img = image.astype(np.float64)
    x1, y1 = np.minimum(ix + 1, Wn - 1), np.minimum(iy + 1, Hn - 1)
    top = img[iy, ix] * (1 - fx) + img[iy, x1] * fx
    bot = img[y1, ix] * (1 - fx) + img[y1, x1] * fx
    return (top * (1 - fy) + bot * fy).astype(np.float32), ok


# ---------------------------------------------------------------------------------------------
# The fused sweep: ZNCC per neighbour, best-k, winner + parabola, tile by tile
# ---------------------------------------------------------------------------------------------
@njit(cache=True, parallel=True, fastmath=_FM, error_model="numpy")
def _zncc_sweep(ref, n_win, sa, va, flat, Hn, Wn, Q, B, s_planes, radius, k, floor_std2, tiles,
                best, value, offset, volume, keep):  # pragma: no cover - compiled
    """See :func:`zncc_sweep`. ref (h, w) float32; n_win, sa, va (h, w) float64 (window count, sum and
    n * variance of the reference); flat (N, Hn * Wn) float32 (the neighbours' rows); Q (N, 3, 3), B (N, 3),
    s_planes (P,) float64; tiles (T, 6) int64 rows (y0, y1, x0, x1, j0, j1): a tile of the reference and the
    planes j0..j1 (inclusive) searched there; outputs best (h, w) int32, value/offset (h, w) float32 and
    volume (h, w, P) float32 when keep (planes outside a tile's range are left as they were).

    Per tile (one work item), per plane, per row of the tile and its halo: each neighbour's samples (the
    tile's columns and the halo's), their squares and their products with the reference go into running
    column sums over the window's rows (a ring holds the last 2 radius + 1 rows); an output row then sums
    its columns across the window, turns the sums into ZNCC per neighbour, keeps the best k (a branch-free
    insertion) and updates the running winner: the planes' costs are never stored unless ``keep``."""
    h, w = ref.shape
    N = flat.shape[0]
    P = s_planes.shape[0]
    L = 2 * radius + 1
    wmax = Wn - 1.0
    hmax = Hn - 1.0
    for ti in prange(tiles.shape[0]):
        y0 = tiles[ti, 0]
        y1 = tiles[ti, 1]
        x0 = tiles[ti, 2]
        x1 = tiles[ti, 3]
        j0 = tiles[ti, 4]
        j1 = tiles[ti, 5]
        bh = y1 - y0
        tw = x1 - x0
        cw = tw + 2 * radius  # sampled columns x0 - radius .. x1 + radius - 1
        ring = np.zeros((N, 3, L, cw), np.float32)
        col = np.zeros((N, 3, cw))
        vring = np.zeros((N, L, tw), np.uint8)
        rb = np.zeros(cw, np.float32)
        zrow = np.empty((N, tw), np.float32)
        kept = np.empty((k, tw), np.float32)
        crow = np.empty(tw, np.float32)
        cin = np.empty(tw, np.float32)
        hs0 = np.empty(tw)
        hs1 = np.empty(tw)
        hs2 = np.empty(tw)
        nwin = np.empty(tw)
        sar = np.empty(tw)
        var_ = np.empty(tw)
        textured = np.empty(tw, np.bool_)
        bc = np.full((bh, tw), np.inf, np.float32)
        bj = np.full((bh, tw), -1, np.int32)
        left = np.full((bh, tw), np.inf, np.float32)
        right = np.full((bh, tw), np.inf, np.float32)
        prev = np.full((bh, tw), np.inf, np.float32)
        xa = max(x0 - radius, 0)  # sampled image columns xa .. xb - 1
        xb = min(x1 + radius, w)
        for j in range(j0, j1 + 1):
            s = s_planes[j]
            ring[:] = 0.0
            col[:] = 0.0
            vring[:] = 0
            for yy in range(y0 - radius, y1 + radius):
                slot = (yy - (y0 - radius)) % L
                inside = 0 <= yy < h
                for n in range(N):
                    if inside:
                        img = flat[n]
                        ax = Q[n, 0, 1] * yy + Q[n, 0, 2] + s * B[n, 0]
                        ay = Q[n, 1, 1] * yy + Q[n, 1, 2] + s * B[n, 1]
                        az = Q[n, 2, 1] * yy + Q[n, 2, 2] + s * B[n, 2]
                        dx = Q[n, 0, 0]
                        dy = Q[n, 1, 0]
                        dz = Q[n, 2, 0]
                        vr = vring[n, slot]
                        for x in range(xa, xb):
                            hz = az + dz * x
                            front = hz > 1e-12
                            inv = 1.0 / (hz if front else 1.0)
                            u = (ax + dx * x) * inv if front else -1.0
                            v = (ay + dy * x) * inv if front else -1.0
                            if x0 <= x < x1:
                                ok = front and (u >= 0.0) and (u <= wmax) and (v >= 0.0) and (v <= hmax)
                                vr[x - x0] = 1 if ok else 0
                            u = min(max(u, 0.0), wmax)
                            v = min(max(v, 0.0), hmax)
                            ix = min(np.int64(u), Wn - 2)
                            iy = min(np.int64(v), Hn - 2)
                            fx = np.float32(u - ix)
                            fy = np.float32(v - iy)
                            o = iy * Wn + ix
                            p00 = img[o]
                            p01 = img[o + 1]
                            p10 = img[o + Wn]
                            p11 = img[o + Wn + 1]
                            top = p00 + (p01 - p00) * fx
                            bot = p10 + (p11 - p10) * fx
                            rb[x - x0 + radius] = top + (bot - top) * fy
                        a_row = ref[yy]
                        for q in range(3):
                            cq = col[n, q]
                            rq = ring[n, q, slot]
                            for x in range(xa, xb):
                                c = x - x0 + radius
                                b = rb[c]
                                val = b if q == 0 else (b * b if q == 1 else a_row[x] * b)
                                cq[c] += np.float64(val) - np.float64(rq[c])
                                rq[c] = val
                    else:
                        vring[n, slot, :] = 0
                        for q in range(3):
                            cq = col[n, q]
                            rq = ring[n, q, slot]
                            for c in range(cw):
                                cq[c] -= np.float64(rq[c])
                                rq[c] = 0.0
                y = yy - radius
                if y < y0:
                    continue
                cslot = (y - (y0 - radius)) % L
                r = y - y0
                for t in range(tw):
                    nwin[t] = n_win[y, x0 + t]
                    sar[t] = sa[y, x0 + t]
                    var_[t] = va[y, x0 + t]
                    textured[t] = va[y, x0 + t] >= n_win[y, x0 + t] * floor_std2
                for n in range(N):
                    c0 = col[n, 0]
                    c1 = col[n, 1]
                    c2 = col[n, 2]
                    vr = vring[n, cslot]
                    zr = zrow[n]
                    for t in range(tw):
                        hs0[t] = c0[t]
                        hs1[t] = c1[t]
                        hs2[t] = c2[t]
                    for d in range(1, L):
                        for t in range(tw):
                            hs0[t] += c0[t + d]
                            hs1[t] += c1[t + d]
                            hs2[t] += c2[t + d]
                    for t in range(tw):
                        nn = nwin[t]
                        sb = hs0[t]
                        vb = hs1[t] - sb * sb / nn
                        z = (hs2[t] - sar[t] * sb / nn) / math.sqrt(max(var_[t] * vb, 1e-30))
                        z = min(1.0, max(-1.0, z))
                        z = z if vb >= nn * floor_std2 else 0.0
                        zr[t] = np.float32(1.0 - z) if vr[t] != 0 else np.float32(1.0)
                for i in range(k):
                    for t in range(tw):
                        kept[i, t] = np.inf
                for n in range(N):
                    zr = zrow[n]
                    for t in range(tw):
                        cin[t] = zr[t]
                    for i in range(k):
                        ki = kept[i]
                        for t in range(tw):
                            lo = min(ki[t], cin[t])
                            cin[t] = max(ki[t], cin[t])
                            ki[t] = lo
                for t in range(tw):
                    acc = np.float32(0.0)
                    for i in range(k):
                        acc += kept[i, t]
                    crow[t] = acc / np.float32(k) if textured[t] else np.float32(np.inf)
                bcr = bc[r]
                bjr = bj[r]
                lr = left[r]
                rr = right[r]
                pr = prev[r]
                for t in range(tw):
                    c = crow[t]
                    if keep:
                        volume[y, x0 + t, j] = c
                    if j > j0 and bjr[t] == j - 1:
                        rr[t] = c
                    if c < bcr[t]:
                        bcr[t] = c
                        bjr[t] = j
                        lr[t] = pr[t]
                    pr[t] = c
        for r in range(bh):
            for t in range(tw):
                b_ = bj[r, t]
                best[y0 + r, x0 + t] = b_
                value[y0 + r, x0 + t] = bc[r, t]
                d = 0.0
                if 0 < b_ < P - 1:
                    d = parabola_vertex(float(left[r, t]), float(bc[r, t]), float(right[r, t]))
                offset[y0 + r, x0 + t] = d


def reference_stats(ref: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Window statistics of a reference (h, w) float32: count, sum and ``n * variance`` (h, w) float64
    (:func:`workers.sweep.costs.window_count` pixels of the (2 radius + 1)^2 window, cut at the border)."""
    ref = np.ascontiguousarray(ref, np.float32)
    h, w = ref.shape
    n = costs.window_count(h, w, radius).astype(np.float64)
    a = ref.astype(np.float64)
    sa = costs.box_sum(ref[:, :, None], radius)[:, :, 0].astype(np.float64)
    saa = costs.box_sum((a * a).astype(np.float32)[:, :, None], radius)[:, :, 0].astype(np.float64)
    return n, sa, saa - sa * sa / n


def zncc_sweep(ref: np.ndarray, images: np.ndarray, Q: np.ndarray, B: np.ndarray, s_planes: np.ndarray,
               radius: int = 2, k: int = 4, min_std: float = 1.5, keep_volume: bool = False,
               windows: tuple[np.ndarray, np.ndarray] | None = None, tile: tuple[int, int] = (32, 128),
               tiles: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Plane sweep with the ZNCC cost, fused (compiled, parallel over tiles of the reference).

    ref (h, w) float32 grey reference; images (N, H, W) float32 grey neighbours (all one size, H, W >= 2);
    Q (N, 3, 3), B (N, 3) float64 from :func:`sweep_geometry`; s_planes (P,) inverse depths (plane 0
    nearest); radius: half the ZNCC window side, px; k: neighbours whose costs are averaged; min_std:
    grey levels (:func:`workers.sweep.costs.zncc_cost`). windows: None (every plane everywhere) or per-pixel
    plane windows (lo, hi) (h, w) int32, inclusive; a tile of ``tile`` (rows, columns) pixels then searches
    the planes its pixels' windows need (:func:`sweep_tiles`; a tile with none is not searched: best -1
    there); tiles: the work items themselves ((T, 6) as :func:`sweep_tiles` makes them), instead.

    The cost of plane j at a pixel is ``best_k_mean([zncc_cost(ref, sample_n, radius, min_std, valid_n)])``
    with ``sample_n`` from :func:`plane_samples`. Returns the winner as :func:`workers.sweep.costs.winner`
    does (best (h, w) int32, -1 where no plane has a cost; value (h, w) float32; offset (h, w) float32 in
    [-0.5, 0.5] planes, 0 at the ends of a tile's range) and the (h, w, P) float32 volume when
    ``keep_volume`` (``inf`` outside the searched planes; else None)."""
    ref = np.ascontiguousarray(ref, np.float32)
    images = np.ascontiguousarray(images, np.float32)
    if images.ndim != 3 or images.shape[0] < 1 or images.shape[1] < 2 or images.shape[2] < 2:
        raise ValueError(f"images must be (N >= 1, H >= 2, W >= 2), got {images.shape}")
    if radius < 0 or k < 1:
        raise ValueError(f"needs radius >= 0 and k >= 1, got radius={radius}, k={k}")
    h, w = ref.shape
    s_planes = np.ascontiguousarray(s_planes, np.float64)
    P = len(s_planes)
    if tiles is None:
        tiles = sweep_tiles(h, w, P, windows, tile, 0.0)
    tiles = np.ascontiguousarray(tiles, np.int64).reshape(-1, 6)
    n, sa, va = reference_stats(ref, radius)
    best = np.full((h, w), -1, np.int32)
    value = np.full((h, w), np.inf, np.float32)
    offset = np.zeros((h, w), np.float32)
    volume = np.full((h, w, P) if keep_volume else (1, 1, 1), np.inf, np.float32)
    N, Hn, Wn = images.shape
    if len(tiles):
        _zncc_sweep(ref, n, sa, va, images.reshape(N, Hn * Wn), Hn, Wn, np.ascontiguousarray(Q, np.float64),
                    np.ascontiguousarray(B, np.float64), s_planes, int(radius), int(min(k, N)),
                    float(min_std) ** 2, tiles, best, value, offset, volume, bool(keep_volume))
    return best, value, offset, (volume if keep_volume else None)


def sweep_tiles(h: int, w: int, planes: int, windows: tuple[np.ndarray, np.ndarray] | None,
                tile: tuple[int, int] = (32, 128), spread: float = 2.0) -> np.ndarray:
    """The work items of :func:`zncc_sweep`: (T, 6) int64 rows (y0, y1, x0, x1, j0, j1), tiles of at most
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
    searches every plane (:func:`depth_map`)."""
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


# ---------------------------------------------------------------------------------------------
# One depth map
# ---------------------------------------------------------------------------------------------
@dataclass
class DepthMap:
    """A reference frame's depth: ``depth`` (h, w) float32 (z, model units; 0 = none), ``cost`` (h, w)
    float32 (the winning plane's cost; inf = none), near/far of the sweep, the neighbours' names."""

    depth: np.ndarray
    cost: np.ndarray
    near: float
    far: float
    neighbours: list[str]
    seconds: float = 0.0


def inverse_depth_planes(near: float, far: float, planes: int) -> np.ndarray:
    """(planes,) float64 inverse depths, uniform from 1/near (plane 0) to 1/far."""
    if not 0 < near < far:
        raise ValueError(f"needs 0 < near < far, got near={near}, far={far}")
    return np.linspace(1.0 / near, 1.0 / far, int(planes))


def depth_map(ref: View, neighbours: Sequence[View], near: float, far: float, planes: int = 128, radius: int = 2,
              k: int = 4, min_std: float = 1.5, max_cost: float = 0.5, aggregation: str = "window",
              sgm_p1: float = 0.05, sgm_p2: float = 0.4, coarse_to_fine: bool = False, margin: int = 4,
              coarse_confidence: float = 0.3) -> DepthMap:
    """Depth map of ``ref`` from ``neighbours`` (all one image size) by the ZNCC plane sweep.

    near, far: the depth range (model units); planes: planes uniform in inverse depth; radius, k, min_std:
    :func:`zncc_sweep`; max_cost: pixels whose winning cost (mean ``1 - ZNCC`` of the best k) is above get
    no depth; aggregation: ``"window"`` (the ZNCC window alone, streamed, low memory) or ``"sgm"``
    (the ZNCC volume smoothed by 8-path semi-global aggregation with penalties ``sgm_p1``/``sgm_p2`` in cost
    units, :func:`workers.sweep.costs.semi_global`; holds the (h, w, planes) volume). coarse_to_fine: first
    the same sweep on every other plane at half resolution, then at full resolution, tile by tile, only the planes
    within ``margin`` of the coarse winners whose cost is at most ``coarse_confidence`` (:func:`coarse_windows`,
    :func:`sweep_tiles`); a winner on the edge of its tile's range is dropped (the minimum may lie beyond)."""
    if aggregation not in ("window", "sgm"):
        raise ValueError(f"aggregation must be 'window' or 'sgm', got {aggregation!r}")
    if not neighbours:
        raise ValueError("a depth map needs at least one neighbour")
    t0 = time.perf_counter()
    sizes = {v.size for v in neighbours}
    if len(sizes) != 1:
        raise ValueError(f"neighbours differ in size: {sorted(sizes)}")
    s_planes = inverse_depth_planes(near, far, planes)
    Q, B = sweep_geometry(ref, neighbours)
    imgs = np.stack([v.gray() for v in neighbours])
    ref_gray = ref.gray()
    tiles = None
    h, w = ref_gray.shape
    P = len(s_planes)
    if coarse_to_fine and min(h, w) >= 16:
        ref_c = ref.scaled(0.5)
        nbr_c = [v.scaled(0.5) for v in neighbours]
        Qc, Bc = sweep_geometry(ref_c, nbr_c)
        # every other plane: at half the resolution a plane step moves a pixel as far as one step at full
        best_c, value_c, _, _ = zncc_sweep(ref_c.gray(), np.stack([v.gray() for v in nbr_c]), Qc, Bc,
                                           s_planes[::2], radius, k, min_std)
        best_c = np.where(best_c >= 0, 2 * best_c, -1)
        windows = coarse_windows(best_c, value_c, h, w, P, margin, coarse_confidence)
        tiles = sweep_tiles(h, w, P, windows)
        # a tile where the coarse search is sure of nothing searches the planes the sure pixels of the whole
        # image use (1st to 99th percentile, widened by twice the margin); all planes when there are none
        sure = (best_c >= 0) & (value_c <= coarse_confidence)
        g0, g1 = 0, P - 1
        if sure.sum() >= 100:
            q0, q1 = np.percentile(best_c[sure], [1, 99])
            g0, g1 = max(0, int(q0) - 2 * margin), min(P - 1, int(np.ceil(q1)) + 2 * margin)
        covered = np.zeros((h, w), bool)
        for y0, y1, x0, x1, _, _ in tiles:
            covered[y0:y1, x0:x1] = True
        rest = [(t[0], t[1], t[2], t[3], g0, g1) for t in sweep_tiles(h, w, P, None)
                if not covered[t[0]:t[1], t[2]:t[3]].any()]
        tiles = np.vstack([tiles, np.asarray(rest, np.int64).reshape(-1, 6)])
    best, value, offset, volume = zncc_sweep(ref_gray, imgs, Q, B, s_planes, radius, k, min_std,
                                             keep_volume=aggregation == "sgm", tiles=tiles)
    if aggregation == "sgm":
        agg = costs.semi_global(np.where(np.isfinite(volume), volume, np.float32(2.0)).astype(np.float32),
                                sgm_p1, sgm_p2, 8)
        agg[~np.isfinite(volume)] = np.inf
        best, _, offset = costs.winner(agg)
        value = np.take_along_axis(volume, np.maximum(best, 0)[:, :, None], 2)[:, :, 0]
        value[best < 0] = np.inf
        del agg, volume
    if tiles is not None:
        # a winner on a tile's first or last plane (not the sweep's) may be a minimum cut off by the range
        j0, j1 = tile_map(tiles, h, w)
        cut = ((best == j0) & (j0 > 0)) | ((best == j1) & (j1 < P - 1))
        value = np.where(cut, np.float32(np.inf), value)
    depth = planes_to_depth(best, offset, s_planes)
    keep = np.isfinite(value) & (value <= max_cost) & (depth > 0)
    depth = np.where(keep, depth, 0.0).astype(np.float32)
    return DepthMap(depth, np.where(keep, value, np.inf).astype(np.float32), float(near), float(far),
                    [v.name for v in neighbours], time.perf_counter() - t0)


def planes_to_depth(best: np.ndarray, offset: np.ndarray, s_planes: np.ndarray) -> np.ndarray:
    """Winner plane (h, w) int32 (-1 = none) and sub-plane offset (h, w) float32 -> depth (h, w) float32
    (0 = none), interpolating linearly in inverse depth between planes."""
    s_planes = np.asarray(s_planes, np.float64)
    P = len(s_planes)
    j = np.clip(best, 0, P - 1).astype(np.float64) + (offset if P > 1 else 0.0)
    step = (s_planes[-1] - s_planes[0]) / max(P - 1, 1)
    s = s_planes[0] + j * step
    with np.errstate(divide="ignore"):
        depth = np.where((best >= 0) & (s > 0), 1.0 / s, 0.0)
    return depth.astype(np.float32)


# ---------------------------------------------------------------------------------------------
# Consistency and fusion
# ---------------------------------------------------------------------------------------------
def backproject(view: View, depth: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """World points (M, 3) float64 of pixels (ys, xs) (M,) of ``view`` at depth (M,) (model units)."""
    Kinv = np.linalg.inv(view.K)
    pix = np.stack([xs, ys, np.ones_like(xs)], 1).astype(np.float64)
    Xc = (pix @ Kinv.T) * np.asarray(depth, np.float64)[:, None]
    return (Xc - view.t) @ view.R


def project(view: View, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (M, 2) float64 and depths (M,) float64 of world points X (M, 3) in ``view``."""
    Xc = np.asarray(X, np.float64) @ view.R.T + view.t
    z = Xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        p = Xc @ view.K.T
        uv = p[:, :2] / p[:, 2:3]
    return uv, z


@dataclass
class Agreement:
    """Which neighbours agree with a reference's depths: ``count`` (h, w) int16 frames that agree,
    the reference included (0 where it has no depth); per neighbour its name and, for every reference
    pixel with a depth (``ys``, ``xs``), whether it agrees (``agree`` (M,) bool), where it landed there
    (``u``, ``v`` (M,) int32) and that neighbour's point (``X`` (M, 3) float64)."""

    count: np.ndarray
    ys: np.ndarray
    xs: np.ndarray
    names: list[str] = field(default_factory=list)
    agree: list[np.ndarray] = field(default_factory=list)
    u: list[np.ndarray] = field(default_factory=list)
    v: list[np.ndarray] = field(default_factory=list)
    X: list[np.ndarray] = field(default_factory=list)


def consistency(ref: View, ref_depth: np.ndarray, others: Sequence[View], other_depths: Sequence[np.ndarray],
                max_reprojection_px: float = 1.0, max_depth_ratio: float = 0.01) -> Agreement:
    """Geometric consistency of ``ref_depth`` (h, w) float32 (0 = none) with each other view's depth map
    (same size as that view's image): the point of a reference pixel is projected into the other view,
    that view's depth at the nearest pixel is back-projected and projected into the reference; it agrees
    when that lands within ``max_reprojection_px`` of the pixel and the two depths in the other view differ
    by at most ``max_depth_ratio`` of its depth."""
    ys, xs = np.nonzero(ref_depth > 0)
    d = ref_depth[ys, xs]
    X = backproject(ref, d, ys, xs)
    count = np.zeros(ref_depth.shape, np.int16)
    count[ys, xs] = 1
    out = Agreement(count, ys.astype(np.int32), xs.astype(np.int32))
    for view, dm in zip(others, other_depths):
        uv, z = project(view, X)
        hn, wn = dm.shape
        u = np.rint(np.nan_to_num(uv[:, 0], nan=-1.0)).astype(np.int64)
        v = np.rint(np.nan_to_num(uv[:, 1], nan=-1.0)).astype(np.int64)
        inside = (z > 0) & (u >= 0) & (v >= 0) & (u < wn) & (v < hn)
        dn = np.zeros(len(d), np.float64)
        dn[inside] = dm[v[inside], u[inside]]
        has = inside & (dn > 0)
        Xn = np.zeros_like(X)
        Xn[has] = backproject(view, dn[has], v[has].astype(np.float64), u[has].astype(np.float64))
        back, _ = project(ref, Xn[has])
        err = np.full(len(d), np.inf)
        err[has] = np.hypot(back[:, 0] - xs[has], back[:, 1] - ys[has])
        ratio = np.full(len(d), np.inf)
        ratio[has] = np.abs(z[has] - dn[has]) / dn[has]
        ok = has & (err <= max_reprojection_px) & (ratio <= max_depth_ratio)
        count[ys[ok], xs[ok]] += 1
        out.names.append(view.name)
        out.agree.append(ok)
        out.u.append(u.astype(np.int32))
        out.v.append(v.astype(np.int32))
        out.X.append(Xn)
    return out


def camera_normals(view: View, depth: np.ndarray, max_jump: float = 0.05) -> np.ndarray:
    """Unit normals (h, w, 3) float32 in world coordinates of a depth map (h, w) float32 (0 = none): the
    cross product of the camera-space points' central differences along x and y (one-sided at a hole or
    where the depth jumps by more than ``max_jump`` of itself), turned towards the camera; where neither
    difference exists, the direction back to the camera."""
    h, w = depth.shape
    Kinv = np.linalg.inv(view.K)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([xs, ys, np.ones_like(xs)], -1) @ Kinv.T
    P = rays * depth[:, :, None].astype(np.float64)
    valid = depth > 0

    def diff(axis: int) -> np.ndarray:
        fwd = np.zeros_like(P)
        bwd = np.zeros_like(P)
        okf = np.zeros((h, w), bool)
        okb = np.zeros((h, w), bool)
        sl_a = [slice(None)] * 2
        sl_b = [slice(None)] * 2
        sl_a[axis] = slice(0, -1)
        sl_b[axis] = slice(1, None)
        a, b = tuple(sl_a), tuple(sl_b)
        near_ = valid[a] & valid[b] & (np.abs(depth[b] - depth[a]) <= max_jump * np.maximum(depth[a], 1e-12))
        fwd[a] = np.where(near_[..., None], P[b] - P[a], 0.0)
        okf[a] = near_
        bwd[b] = np.where(near_[..., None], P[b] - P[a], 0.0)
        okb[b] = near_
        both = okf & okb
        d = np.where(both[..., None], 0.5 * (fwd + bwd), fwd + bwd)
        return d, okf | okb

    dx, okx = diff(1)
    dy, oky = diff(0)
    n = np.cross(dx, dy)
    norm = np.linalg.norm(n, axis=-1)
    good = okx & oky & (norm > 0)
    toward = -rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    n = np.where(good[..., None], n / np.where(norm > 0, norm, 1.0)[..., None], toward)
    flip = np.sum(n * rays, axis=-1) > 0
    n[flip] *= -1
    return (n @ view.R).astype(np.float32)


@dataclass
class DenseCloud:
    """Fused points: ``points`` (M, 3) float32 world, ``colors`` (M, 3) uint8 BGR, ``normals`` (M, 3) float32
    unit, ``views`` (M,) uint8 frames that agree on each point (the reference included)."""

    points: np.ndarray
    colors: np.ndarray
    normals: np.ndarray
    views: np.ndarray

    def __len__(self) -> int:
        return len(self.points)


@njit(cache=True, parallel=True, error_model="numpy")
def _fuse_view(free, dm, Kinv, K, R, t, image, nK, nKinv, nR, nt, ndepth, nimage, max_err, max_ratio, min_views,
               max_jump, count, X, col, nrm, nused):  # pragma: no cover - compiled
    """:func:`fuse` for one reference: free (h, w) float32 its depths not yet used, dm (h, w) float32 its whole
    depth map (normals), Kinv/K/R (3, 3), t (3,) float64, image (h, w, 3) uint8; the N neighbours' nK, nKinv,
    nR (N, 3, 3), nt (N, 3), ndepth (N, hn, wn) float32, nimage (N, hn, wn, 3) uint8. Writes, per reference
    pixel with a depth, count (h, w) int16 (agreeing frames, the reference included), X (h, w, 3) the mean
    point, col (h, w, 3) the mean colour, nrm (h, w, 3) the world normal; marks nused (N, hn, wn) at the
    neighbour pixels that agreed with a pixel kept (count >= min_views). Same tests as :func:`consistency`."""
    h, w = free.shape
    N = ndepth.shape[0]
    hn = ndepth.shape[1]
    wn = ndepth.shape[2]
    for y in prange(h):
        us = np.empty(N, np.int64)
        vs = np.empty(N, np.int64)
        ok = np.zeros(N, np.bool_)
        for x in range(w):
            d = free[y, x]
            count[y, x] = 0
            if not d > 0:
                continue
            cx = d * (Kinv[0, 0] * x + Kinv[0, 1] * y + Kinv[0, 2])
            cy = d * (Kinv[1, 0] * x + Kinv[1, 1] * y + Kinv[1, 2])
            cz = d * (Kinv[2, 0] * x + Kinv[2, 1] * y + Kinv[2, 2])
            px = cx - t[0]
            py = cy - t[1]
            pz = cz - t[2]
            Xw0 = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
            Xw1 = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
            Xw2 = R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz
            s0 = Xw0
            s1 = Xw1
            s2 = Xw2
            c0 = float(image[y, x, 0])
            c1 = float(image[y, x, 1])
            c2 = float(image[y, x, 2])
            cnt = 1
            for n in range(N):
                ok[n] = False
                qx = nR[n, 0, 0] * Xw0 + nR[n, 0, 1] * Xw1 + nR[n, 0, 2] * Xw2 + nt[n, 0]
                qy = nR[n, 1, 0] * Xw0 + nR[n, 1, 1] * Xw1 + nR[n, 1, 2] * Xw2 + nt[n, 1]
                qz = nR[n, 2, 0] * Xw0 + nR[n, 2, 1] * Xw1 + nR[n, 2, 2] * Xw2 + nt[n, 2]
                if not qz > 0:
                    continue
                hx = nK[n, 0, 0] * qx + nK[n, 0, 1] * qy + nK[n, 0, 2] * qz
                hy = nK[n, 1, 0] * qx + nK[n, 1, 1] * qy + nK[n, 1, 2] * qz
                hz = nK[n, 2, 0] * qx + nK[n, 2, 1] * qy + nK[n, 2, 2] * qz
                u = np.rint(hx / hz)
                v = np.rint(hy / hz)
                if not (u >= 0 and v >= 0 and u < wn and v < hn):
                    continue
                ui = np.int64(u)
                vi = np.int64(v)
                dn = float(ndepth[n, vi, ui])
                if not dn > 0:
                    continue
                ax = dn * (nKinv[n, 0, 0] * u + nKinv[n, 0, 1] * v + nKinv[n, 0, 2]) - nt[n, 0]
                ay = dn * (nKinv[n, 1, 0] * u + nKinv[n, 1, 1] * v + nKinv[n, 1, 2]) - nt[n, 1]
                az = dn * (nKinv[n, 2, 0] * u + nKinv[n, 2, 1] * v + nKinv[n, 2, 2]) - nt[n, 2]
                Y0 = nR[n, 0, 0] * ax + nR[n, 1, 0] * ay + nR[n, 2, 0] * az
                Y1 = nR[n, 0, 1] * ax + nR[n, 1, 1] * ay + nR[n, 2, 1] * az
                Y2 = nR[n, 0, 2] * ax + nR[n, 1, 2] * ay + nR[n, 2, 2] * az
                rx = R[0, 0] * Y0 + R[0, 1] * Y1 + R[0, 2] * Y2 + t[0]
                ry = R[1, 0] * Y0 + R[1, 1] * Y1 + R[1, 2] * Y2 + t[1]
                rz = R[2, 0] * Y0 + R[2, 1] * Y1 + R[2, 2] * Y2 + t[2]
                gx = K[0, 0] * rx + K[0, 1] * ry + K[0, 2] * rz
                gy = K[1, 0] * rx + K[1, 1] * ry + K[1, 2] * rz
                gz = K[2, 0] * rx + K[2, 1] * ry + K[2, 2] * rz
                err = math.hypot(gx / gz - x, gy / gz - y)
                if not (err <= max_err and abs(qz - dn) / dn <= max_ratio):
                    continue
                ok[n] = True
                us[n] = ui
                vs[n] = vi
                s0 += Y0
                s1 += Y1
                s2 += Y2
                c0 += float(nimage[n, vi, ui, 0])
                c1 += float(nimage[n, vi, ui, 1])
                c2 += float(nimage[n, vi, ui, 2])
                cnt += 1
            count[y, x] = min(cnt, 32767)
            if cnt < min_views:
                continue
            X[y, x, 0] = s0 / cnt
            X[y, x, 1] = s1 / cnt
            X[y, x, 2] = s2 / cnt
            col[y, x, 0] = c0 / cnt
            col[y, x, 1] = c1 / cnt
            col[y, x, 2] = c2 / cnt
            for n in range(N):
                if ok[n]:
                    nused[n, vs[n], us[n]] = True
            # the normal: central differences of the camera-space points (one-sided at a hole or a jump)
            e = dm[y, x]
            P0 = e * (Kinv[0, 0] * x + Kinv[0, 1] * y + Kinv[0, 2])
            P1 = e * (Kinv[1, 0] * x + Kinv[1, 1] * y + Kinv[1, 2])
            P2 = e * (Kinv[2, 0] * x + Kinv[2, 1] * y + Kinv[2, 2])
            dxv = np.zeros(3)
            dyv = np.zeros(3)
            okx = False
            oky = False
            for axis in range(2):
                acc = np.zeros(3)
                m = 0
                for si in range(2):
                    step = 2 * si - 1
                    xx = np.int64(x) + (step if axis == 0 else 0)
                    yy = np.int64(y) + (step if axis == 1 else 0)
                    if xx < 0 or yy < 0 or xx >= w or yy >= h:
                        continue
                    f = dm[yy, xx]
                    base = f if step < 0 else e  # the jump is measured against the first pixel of the pair
                    if not (f > 0 and abs(f - e) <= max_jump * max(base, 1e-12)):
                        continue
                    Q0 = f * (Kinv[0, 0] * xx + Kinv[0, 1] * yy + Kinv[0, 2])
                    Q1 = f * (Kinv[1, 0] * xx + Kinv[1, 1] * yy + Kinv[1, 2])
                    Q2 = f * (Kinv[2, 0] * xx + Kinv[2, 1] * yy + Kinv[2, 2])
                    acc[0] += (Q0 - P0) * step
                    acc[1] += (Q1 - P1) * step
                    acc[2] += (Q2 - P2) * step
                    m += 1
                if m > 0:
                    if axis == 0:
                        dxv[:] = acc / m
                        okx = True
                    else:
                        dyv[:] = acc / m
                        oky = True
            n0 = dxv[1] * dyv[2] - dxv[2] * dyv[1]
            n1 = dxv[2] * dyv[0] - dxv[0] * dyv[2]
            n2 = dxv[0] * dyv[1] - dxv[1] * dyv[0]
            norm = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
            r0 = Kinv[0, 0] * x + Kinv[0, 1] * y + Kinv[0, 2]
            r1 = Kinv[1, 0] * x + Kinv[1, 1] * y + Kinv[1, 2]
            r2 = Kinv[2, 0] * x + Kinv[2, 1] * y + Kinv[2, 2]
            if okx and oky and norm > 0:
                n0 /= norm
                n1 /= norm
                n2 /= norm
            else:
                rn = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
                n0 = -r0 / rn
                n1 = -r1 / rn
                n2 = -r2 / rn
            if n0 * r0 + n1 * r1 + n2 * r2 > 0:
                n0 = -n0
                n1 = -n1
                n2 = -n2
            nrm[y, x, 0] = R[0, 0] * n0 + R[1, 0] * n1 + R[2, 0] * n2
            nrm[y, x, 1] = R[0, 1] * n0 + R[1, 1] * n1 + R[2, 1] * n2
            nrm[y, x, 2] = R[0, 2] * n0 + R[1, 2] * n1 + R[2, 2] * n2


def fuse(views: Sequence[View], depths: Sequence[np.ndarray], neighbours: Sequence[Sequence[int]],
         min_views: int = 3, max_reprojection_px: float = 1.0, max_depth_ratio: float = 0.01,
         progress: Callable[[int], None] | None = None, max_jump: float = 0.05) -> DenseCloud:
    """Fuse the depth maps (one per view, each (h, w) float32 at its view's size, 0 = none) into one cloud.

    neighbours[i]: indices of the views checked against view i (the tests of :func:`consistency`; all views
    one image size). A pixel whose depth at least ``min_views`` frames agree on (the reference included)
    becomes a point: the mean of the agreeing frames' points and of their colours, the reference's normal
    (:func:`camera_normals`, ``max_jump``). Views are taken in order; the neighbour pixels that agreed are
    then marked used and never start a point of their own. ``progress(i)`` is called after view i.
    Compiled, one pass over the pixels per reference (:func:`_fuse_view`)."""
    used = [np.zeros(d.shape, bool) for d in depths]
    pts, cols, nrms, cnts = [], [], [], []
    for i, (view, dm) in enumerate(zip(views, depths)):
        free = np.where(used[i], 0.0, dm).astype(np.float32)
        nb = [j for j in neighbours[i] if j != i]
        h, w = dm.shape
        hn, wn = (depths[nb[0]].shape if nb else (1, 1))
        f64 = np.float64
        nK = np.stack([views[j].K for j in nb]).astype(f64) if nb else np.zeros((0, 3, 3))
        nKinv = np.stack([np.linalg.inv(views[j].K) for j in nb]).astype(f64) if nb else np.zeros((0, 3, 3))
        nR = np.stack([views[j].R for j in nb]).astype(f64) if nb else np.zeros((0, 3, 3))
        nt = np.stack([views[j].t for j in nb]).astype(f64) if nb else np.zeros((0, 3))
        ndepth = np.stack([depths[j] for j in nb]).astype(np.float32) if nb else np.zeros((0, 1, 1), np.float32)
        nimage = np.stack([views[j].image for j in nb]) if nb else np.zeros((0, 1, 1, 3), np.uint8)
        count = np.zeros((h, w), np.int16)
        X = np.zeros((h, w, 3), np.float32)
        col = np.zeros((h, w, 3), np.float32)
        nrm = np.zeros((h, w, 3), np.float32)
        nused = np.zeros((len(nb), hn, wn), np.bool_)
        _fuse_view(free, np.ascontiguousarray(dm, np.float32), np.linalg.inv(view.K), view.K.astype(f64),
                   view.R.astype(f64), view.t.astype(f64), np.ascontiguousarray(view.image), nK, nKinv, nR, nt,
                   ndepth, np.ascontiguousarray(nimage), float(max_reprojection_px), float(max_depth_ratio),
                   int(min_views), float(max_jump), count, X, col, nrm, nused)
        keep = (count >= min_views) & (free > 0)
        if keep.any():
            pts.append(X[keep])
            cols.append(np.clip(np.rint(col[keep]), 0, 255).astype(np.uint8))
            nrms.append(nrm[keep])
            cnts.append(np.minimum(count[keep], 255).astype(np.uint8))
            used[i] |= keep
            for k_, j in enumerate(nb):
                used[j] |= nused[k_]
        if progress is not None:
            progress(i)
    if not pts:
        return DenseCloud(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8), np.zeros((0, 3), np.float32),
                          np.zeros(0, np.uint8))
    return DenseCloud(np.concatenate(pts), np.concatenate(cols), np.concatenate(nrms), np.concatenate(cnts))


# ---------------------------------------------------------------------------------------------
# Neighbours and depth ranges from the sparse model
# ---------------------------------------------------------------------------------------------
def visible_points(view: View, points: np.ndarray) -> np.ndarray:
    """Indices (M,) int64 of ``points`` (P, 3) in front of ``view`` and inside its image."""
    if len(points) == 0:
        return np.zeros(0, np.int64)
    uv, z = project(view, points)
    w, h = view.size
    ok = (z > 0) & (uv[:, 0] >= -0.5) & (uv[:, 1] >= -0.5) & (uv[:, 0] <= w - 0.5) & (uv[:, 1] <= h - 0.5)
    return np.flatnonzero(ok)


def triangulation_weight(angle_deg: np.ndarray, best_deg: float = 5.0) -> np.ndarray:
    """Weight of a shared point by the angle (degrees) between its two rays: 1 at ``best_deg``, a Gaussian
    of sigma 1 deg below it (little depth resolution) and of sigma 10 deg above (harder matching)."""
    a = np.asarray(angle_deg, np.float64)
    sigma = np.where(a <= best_deg, 1.0, 10.0)
    return np.exp(-((a - best_deg) ** 2) / (2 * sigma**2))


def select_neighbours(views: Sequence[View], points: np.ndarray, seen: Sequence[np.ndarray], ref: int,
                      count: int, best_deg: float = 5.0) -> list[int]:
    """The ``count`` best neighbours of view ``ref`` (indices into ``views``, best first).

    points (P, 3) sparse points; seen[i] (M_i,) indices of the points view i sees. Score of view j: the
    sum over the points both see of :func:`triangulation_weight` of the angle between the two rays; only
    views with a positive score (a shared point) qualify."""
    mine = np.asarray(seen[ref])
    scores = []
    for j in range(len(views)):
        if j == ref:
            continue
        shared = np.intersect1d(mine, seen[j], assume_unique=True)
        if len(shared) == 0:
            continue
        X = points[shared]
        a = X - views[ref].center
        b = X - views[j].center
        cosang = np.sum(a * b, 1) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
        angle = np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))
        score = float(triangulation_weight(angle, best_deg).sum())
        if score > 0:
            scores.append((score, j))
    scores.sort(key=lambda sj: (-sj[0], sj[1]))
    return [j for _, j in scores[:count]]


def depth_range(view: View, points: np.ndarray, margin: float = 0.25, percentile: float = 1.0
                ) -> tuple[float, float] | None:
    """(near, far) of the sparse points (P, 3) the view sees: their depths' ``percentile`` and
    ``100 - percentile`` percentiles, widened by ``margin`` (near / (1 + margin), far * (1 + margin));
    None when it sees fewer than 10."""
    idx = visible_points(view, points)
    if len(idx) < 10:
        return None
    _, z = project(view, points[idx])
    lo, hi = np.percentile(z, [percentile, 100 - percentile])
    if not hi > 0:
        return None
    lo = max(lo, hi * 1e-3)
    return float(lo / (1 + margin)), float(hi * (1 + margin))


# ---------------------------------------------------------------------------------------------
# Outputs: depth PNGs and the PLY with normals
# ---------------------------------------------------------------------------------------------
def depth_png(depth: np.ndarray, far: float) -> tuple[bytes, float]:
    """16-bit PNG of a depth map (h, w) float32 (0 = none) and its scale (model units per level):
    level = round(depth / scale), scale = far / 65535, 0 = no depth."""
    scale = float(far) / DEPTH_PNG_LEVELS
    levels = np.clip(np.rint(depth / scale), 0, DEPTH_PNG_LEVELS).astype(np.uint16)
    levels[depth <= 0] = 0
    ok, buf = cv2.imencode(".png", levels)
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes(), scale


def dense_ply_bytes(cloud: DenseCloud) -> bytes:
    """Binary little-endian PLY: x y z (float), nx ny nz (float), red green blue (uchar) and ``views``
    (uchar, frames that agree), as MeshLab and CloudCompare read it."""
    v = np.empty(len(cloud), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"),
                                     ("nz", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"), ("views", "u1")])
    for i, c in enumerate("xyz"):
        v[c] = cloud.points[:, i]
        v["n" + c] = cloud.normals[:, i]
    v["red"], v["green"], v["blue"] = cloud.colors[:, 2], cloud.colors[:, 1], cloud.colors[:, 0]
    v["views"] = cloud.views
    header = ("ply\nformat binary_little_endian 1.0\ncomment sweepcast dense reconstruction\n"
              f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
              "property float nx\nproperty float ny\nproperty float nz\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar views\nend_header\n")
    return header.encode("ascii") + v.tobytes()


def read_ply(data: bytes) -> np.ndarray:
    """A binary little-endian PLY's vertices as a numpy structured array (the writers' inverse)."""
    end = data.index(b"end_header\n") + len(b"end_header\n")
    lines = data[:end].decode("ascii").split("\n")
    if "format binary_little_endian 1.0" not in lines:
        raise ValueError("not a binary little-endian PLY")
    types = {"float": "<f4", "uchar": "u1", "int": "<i4", "double": "<f8"}
    dtype = [(ln.split()[2], types[ln.split()[1]]) for ln in lines if ln.startswith("property ")]
    n = next(int(ln.split()[2]) for ln in lines if ln.startswith("element vertex"))
    return np.frombuffer(data, dtype=dtype, count=n, offset=end)


def depth_zip(names: Sequence[str], pngs: Sequence[bytes]) -> bytes:
    """A zip of ``<frame name without suffix>.png`` files (stored: PNG is already compressed)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as zf:
        for name, png in zip(names, pngs):
            zf.writestr(f"{_stem(name)}.png", png)
    return buf.getvalue()


def summary_stats(values: Sequence[float]) -> dict[str, Any]:
    """{'mean', 'median', 'max'} of a list of numbers (None when empty)."""
    a = np.asarray(values, np.float64)
    if len(a) == 0:
        return {"mean": None, "median": None, "max": None}
    return {"mean": float(a.mean()), "median": float(np.median(a)), "max": float(a.max())}


# ---------------------------------------------------------------------------------------------
# The dense pass of a reconstruction
# ---------------------------------------------------------------------------------------------
@dataclass
class DenseResult:
    """What :func:`densify` made: the fused ``cloud``, the reference frames' ``names`` and ``depths``
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


def densify(model, images: dict[int, np.ndarray], p, progress: ProgressFn | None = None) -> DenseResult:
    """The dense pass over a sparse model (:class:`~workers.drone.reconstruction.SparseModel`).

    images: frame position in the model -> (h, w, 3) uint8 BGR at the working resolution, for (at least)
    the frames :func:`reference_frames` picks (``model.registered``, ``p.dense_frames``; see
    :func:`workers.drone.frames.load_frames`); p: the :class:`~workers.drone.params.ReconstructionParams`
    (its ``dense_*`` fields). Each reference's neighbours are chosen among the other references, so every
    neighbour has a depth map to check consistency against. ``progress(fraction, stage)`` goes from 0 to 1
    with stages 'dense depth k/M' (one per depth map) and 'dense fusion'. Raises ValueError when fewer than
    two registered frames have images."""
    refs = [int(f) for f in reference_frames(model.registered, p.dense_frames) if int(f) in images]
    if len(refs) < 2:
        raise ValueError("a dense reconstruction needs at least two registered frames")
    views = [View(model.frame_name[f], images[f], model.K, model.R[f], model.t[f]).scaled(p.dense_scale)
             for f in refs]
    # what each frame sees of the sparse points: its bundle-adjustment observations, else the points in view
    seen = []
    for f, v in zip(refs, views):
        obs = np.unique(model.obs_point[model.obs_frame == f])
        seen.append(obs if len(obs) >= 30 else visible_points(v, model.points))
    return densify_views(views, model.points, seen, p, progress)


def densify_views(views: Sequence[View], points: np.ndarray, seen: Sequence[np.ndarray], p,
                  progress: ProgressFn | None = None) -> DenseResult:
    """:func:`densify` on posed views (each one its own reference, the others its candidate neighbours):
    points (P, 3) the sparse points, seen[i] the indices of those view i sees (neighbour choice and depth
    range); p the ``dense_*`` settings (:class:`~workers.drone.params.ReconstructionParams` or anything
    with those attributes)."""
    t_all = time.perf_counter()
    refs = list(range(len(views)))
    views = dict(enumerate(views))
    seen = dict(enumerate(seen))
    points = np.asarray(points, np.float64).reshape(-1, 3)
    view_list = [views[f] for f in refs]
    seen_list = [seen[f] for f in refs]
    radius = p.dense_window // 2
    depths: dict[int, np.ndarray] = {}
    items: dict[int, dict[str, Any]] = {}
    neighbours: dict[int, list[int]] = {}
    for i, f in enumerate(refs):
        if progress is not None:
            progress(0.9 * i / len(refs), f"dense depth {i + 1}/{len(refs)}")
        nb = select_neighbours(view_list, points, seen_list, i, p.dense_neighbours)
        rng_ = depth_range(views[f], points[seen[f]] if len(seen[f]) >= 10 else points)
        item: dict[str, Any] = {"frame": views[f].name, "neighbours": [views[refs[j]].name for j in nb]}
        items[f] = item
        if not nb or rng_ is None:
            item["skipped"] = "no other frame shares sparse points" if not nb else "too few sparse points in view"
            continue
        near, far = rng_
        dm = depth_map(views[f], [view_list[j] for j in nb], near, far, p.dense_planes, radius,
                       min(p.dense_best_k, len(nb)), p.dense_min_texture, p.dense_max_cost, p.dense_aggregation,
                       coarse_to_fine=p.dense_coarse_to_fine)
        depths[f] = dm.depth
        neighbours[f] = [refs[j] for j in nb]
        png, scale = depth_png(dm.depth, far)
        item.update(near=near, far=far, seconds=round(dm.seconds, 3), valid_fraction=float((dm.depth > 0).mean()),
                    file=f"{_stem(views[f].name)}.png", depth_scale=scale, png=png)
    if progress is not None:
        progress(0.9, "dense fusion")
    t0 = time.perf_counter()
    done = [f for f in refs if f in depths]
    idx = {f: i for i, f in enumerate(done)}
    cloud = fuse([views[f] for f in done], [depths[f] for f in done],
                 [[idx[g] for g in neighbours[f] if g in idx] for f in done], p.dense_min_views,
                 p.dense_max_reprojection, p.dense_max_depth_error)
    t_fuse = time.perf_counter() - t0
    pngs = [items[f].pop("png") for f in done]
    secs = [items[f]["seconds"] for f in done]
    h, w = view_list[0].image.shape[:2]
    report = {
        "reference_frames": len(refs),
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
        "seconds_per_depth_map": summary_stats(secs),
        "seconds_fusion": round(t_fuse, 3),
        "seconds_total": round(time.perf_counter() - t_all, 3),
        "depth_png": "depth.zip holds <frame>.png per depth map: 16-bit, depth = level * depth_scale (model units, "
                     "z along the optical axis), 0 = no depth; pixels at the dense resolution",
        "frames": [items[f] for f in refs],
    }
    if progress is not None:
        progress(1.0, "dense fusion")
    return DenseResult(cloud, [views[f].name for f in done], [depths[f] for f in done], pngs, report)


def _stem(name: str) -> str:
    """A frame name without its image suffix, safe as a file name in a zip."""
    stem = name.rsplit(".", 1)[0] if "." in name else name
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in stem) or "frame"
