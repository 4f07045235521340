"""The fused ZNCC plane sweep: per tile of the reference, ZNCC per neighbour, the mean of the best k, the
winning plane and a parabola through its neighbours' costs, in one compiled pass."""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from workers.sweep import costs
from workers.sweep.costs import parabola_vertex

from .tiles import sweep_tiles

_FM = {"nsz", "contract", "arcp", "reassoc"}  # never "nnan"/"ninf": inf marks a pixel without a cost


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
    Q (N, 3, 3), B (N, 3) float64 from :func:`.homography.sweep_geometry`; s_planes (P,) inverse depths (plane 0
    nearest); radius: half the ZNCC window side, px; k: neighbours whose costs are averaged; min_std:
    grey levels (:func:`workers.sweep.costs.zncc_cost`). windows: None (every plane everywhere) or per-pixel
    plane windows (lo, hi) (h, w) int32, inclusive; a tile of ``tile`` (rows, columns) pixels then searches
    the planes its pixels' windows need (:func:`.tiles.sweep_tiles`; a tile with none is not searched: best -1
    there); tiles: the work items themselves ((T, 6) as :func:`.tiles.sweep_tiles` makes them), instead.

    The cost of plane j at a pixel is ``best_k_mean([zncc_cost(ref, sample_n, radius, min_std, valid_n)])``
    with ``sample_n`` from :func:`.homography.plane_samples`. Returns the winner as :func:`workers.sweep.costs.winner`
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
