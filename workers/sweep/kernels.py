"""Fused, compiled plane-sweep kernels (numba, parallel over virtual image rows).

Geometry shared by both kernels: for virtual pixel (x, y) and plane ``j`` at inverse depth
``s = 1/z``, camera ``i`` sees the point at homogeneous pixel ``a_i(x, y) + s * B[i]`` with
``a_i = Q[i] @ (x, y, 1)``: ``Q[i] = M_i G`` and ``B[i] = M_i C_v + p_i`` for the camera's
``P_i = [M_i | p_i]``, the virtual centre ``C_v`` and ``G = R_v^T K_v^-1`` (the virtual ray
through (x, y) with unit depth). This is the plane-induced homography ``Q[i] + s B[i] e3^T`` in
a form that costs three multiply-adds per camera and plane.

A camera votes at a plane when the point is in front of it and projects inside its image
(``0 <= u <= W-1``, ``0 <= v <= H-1``: all four bilinear taps exist). With the visual hull on, a
point that projects inside some camera's image but outside its silhouette is outside the hull and
the plane is not tested for that pixel.

The hot loops index arrays directly instead of calling helpers that take arrays: numba would
reference-count every such call (atomic operations), which cost more than the arithmetic.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from .weighting import kojima_weights, ulr_weights

_Z_MIN = 1e-9
_BIG = 1e300  # "no plane yet": finite, so that bc * n stays a valid bound
# fast-math without the no-NaN/no-inf assumptions (the kernels compare against infinities) and without
# approximate reciprocals (x / n must stay exact so that equal samples give exactly zero variance)
_FAST = {"nsz", "contract", "afn", "reassoc"}
GLOBAL, NEAREST, ULR, KOJIMA = 0, 1, 2, 3


@njit(cache=True, inline="always", fastmath=_FAST)
def _lerp2(a, b, c, d, fx, fy):  # pragma: no cover - compiled
    """Bilinear blend of a (top-left), b (top-right), c (bottom-left), d (bottom-right), written as
    nested lerps so that a uniform patch gives its value exactly (no spurious ties in the sweep)."""
    top = a + fx * (b - a)
    bot = c + fx * (d - c)
    return top + fy * (bot - top)


@njit(cache=True, inline="always", fastmath=_FAST)
def _project(ax, ay, az, bx, by, bz, s, qs, inv_qs, wl, hl):  # pragma: no cover - compiled
    """Camera pixel (u, v) of the homogeneous point (ax, ay, az) + s (bx, by, bz); ok is False when
    it is behind the camera or outside [0, wl] x [0, hl]. qs > 0 rounds to multiples of 1/qs."""
    zc = az + s * bz
    if zc <= _Z_MIN:
        return False, 0.0, 0.0
    inv = 1.0 / zc
    u = (ax + s * bx) * inv
    v = (ay + s * by) * inv
    if qs > 0:
        u = np.rint(u * qs) * inv_qs
        v = np.rint(v * qs) * inv_qs
    return u >= 0.0 and v >= 0.0 and u <= wl and v <= hl, u, v


# per-camera table of sweep_depth: Q (9), B (3), W-1, H-1, image offset, image row stride,
# silhouette offset, silhouette row stride
CAM_COLUMNS = 18


@njit(cache=True, parallel=True, fastmath=_FAST)
def sweep_depth(cam, flat, silflat, use_hull, min_views, trunc2, qs, s_planes, lo, hi, best,
                best_cost):  # pragma: no cover - compiled
    """Most photo-consistent plane per virtual pixel.

    cam (N, CAM_COLUMNS) float64, one row per camera in sampling order (widely spread cameras
    first, so that a wrong plane shows early): Q row-major (9), B (3), W-1, H-1, offset and row
    stride of its image in ``flat``, offset and row stride of its silhouette in ``silflat`` (see
    the module docstring for Q and B). flat: all images, uint8 BGR, flattened; silflat:
    all silhouettes, uint8, flattened (used when ``use_hull``). trunc2 > 0 selects the truncated
    cost ``mean_i min(|c_i - mean|^2, trunc2)``, else the variance summed over channels. qs > 0
    rounds sampling positions to multiples of 1/qs px (qs = 32 reproduces OpenCV's warps).
    s_planes (P,) inverse depths; lo, hi (h, w) int32: inclusive plane window per pixel.
    Writes best (h, w) int32 (-1: no plane with >= min_views votes inside the hull) and best_cost
    (h, w) float32 (inf where best is -1). Ties go to the nearer plane (smaller index).

    Exact pruning (variance cost): the plane chosen by the previous pixel of the row is tested
    first, and a plane is abandoned once the cameras sampled so far prove that it cannot beat the
    best one: their squared deviations from their own mean bound n times the cost from below, with
    n at most the voters so far plus the cameras left. The result equals the full search.
    """
    N = cam.shape[0]
    h, w = best.shape
    inv_qs = 1.0 / qs if qs > 0 else 0.0
    prune = trunc2 <= 0
    for y in prange(h):
        ax = np.empty(N)
        ay = np.empty(N)
        az = np.empty(N)
        us = np.empty(N)
        vs = np.empty(N)
        idx = np.empty(N, np.int64)
        smp = np.empty((N, 3))
        first = 0  # the camera that culled last is tried first: it usually culls again
        guess = -1
        for x in range(w):
            j0 = lo[y, x]
            j1 = hi[y, x]
            bc = _BIG
            bj = -1
            if j0 <= j1:
                for i in range(N):
                    ax[i] = cam[i, 0] * x + cam[i, 1] * y + cam[i, 2]
                    ay[i] = cam[i, 3] * x + cam[i, 4] * y + cam[i, 5]
                    az[i] = cam[i, 6] * x + cam[i, 7] * y + cam[i, 8]
            start = guess if j0 <= guess <= j1 else j0
            for jj in range(j0 - 1, j1 + 1):
                j = start if jj < j0 else jj
                if jj >= j0 and j == start:
                    continue
                s = s_planes[j]
                steps = N
                if use_hull:
                    # the hull needs every camera's verdict before any sampling
                    steps = 0
                    inside = True
                    for kk in range(N):
                        i = kk + first
                        if i >= N:
                            i -= N
                        ok, u, v = _project(ax[i], ay[i], az[i], cam[i, 9], cam[i, 10], cam[i, 11], s, qs, inv_qs,
                                            cam[i, 12], cam[i, 13])
                        if not ok:
                            continue
                        o = np.int64(cam[i, 16]) + np.int64(v + 0.5) * np.int64(cam[i, 17]) + np.int64(u + 0.5)
                        if silflat[o] == 0:
                            inside = False
                            first = i
                            break
                        us[steps] = u
                        vs[steps] = v
                        idx[steps] = i
                        steps += 1
                    if not inside or steps < min_views:
                        continue
                # sample and score, abandoning the plane once it cannot win
                s0 = 0.0
                s1 = 0.0
                s2 = 0.0
                q = 0.0
                n = 0
                pruned = False
                for m in range(steps):
                    if use_hull:
                        i = idx[m]
                        u = us[m]
                        v = vs[m]
                    else:
                        i = m
                        ok, u, v = _project(ax[i], ay[i], az[i], cam[i, 9], cam[i, 10], cam[i, 11], s, qs, inv_qs,
                                            cam[i, 12], cam[i, 13])
                        if not ok:
                            continue
                    x0 = np.int64(u)
                    y0 = np.int64(v)
                    fx = u - x0
                    fy = v - y0
                    row = np.int64(cam[i, 15])
                    dx = 3 if u < cam[i, 12] else 0
                    dy = row if v < cam[i, 13] else 0
                    o = np.int64(cam[i, 14]) + y0 * row + 3 * x0
                    c0 = _lerp2(np.float64(flat[o]), np.float64(flat[o + dx]), np.float64(flat[o + dy]),
                                np.float64(flat[o + dy + dx]), fx, fy)
                    o += 1
                    c1 = _lerp2(np.float64(flat[o]), np.float64(flat[o + dx]), np.float64(flat[o + dy]),
                                np.float64(flat[o + dy + dx]), fx, fy)
                    o += 1
                    c2 = _lerp2(np.float64(flat[o]), np.float64(flat[o + dx]), np.float64(flat[o + dy]),
                                np.float64(flat[o + dy + dx]), fx, fy)
                    s0 += c0
                    s1 += c1
                    s2 += c2
                    q += c0 * c0 + c1 * c1 + c2 * c2
                    smp[n, 0] = c0
                    smp[n, 1] = c1
                    smp[n, 2] = c2
                    n += 1
                    if prune and n >= 2:
                        # SSD of the n samples so far <= n_all x cost, n_all <= n + cameras left: prune
                        # when SSD > n_all x best, in the division-free form n SSD > n n_all best
                        n_all = n + steps - 1 - m
                        lhs = n * q - (s0 * s0 + s1 * s1 + s2 * s2)
                        rhs = bc * n * n_all
                        if lhs > rhs or (lhs == rhs and j > bj):
                            pruned = True
                            break
                if pruned or n < min_views:
                    continue
                if trunc2 > 0:
                    m0 = s0 / n
                    m1 = s1 / n
                    m2 = s2 / n
                    cost = 0.0
                    for m in range(n):
                        d = (smp[m, 0] - m0) ** 2 + (smp[m, 1] - m1) ** 2 + (smp[m, 2] - m2) ** 2
                        cost += d if d < trunc2 else trunc2
                    cost /= n
                else:
                    cost = (n * q - (s0 * s0 + s1 * s1 + s2 * s2)) / (n * n)
                if cost < bc or (cost == bc and j < bj):
                    bc = cost
                    bj = j
            best[y, x] = bj
            best_cost[y, x] = bc if bj >= 0 else np.inf
            if bj >= 0:
                guess = bj


@njit(cache=True, parallel=True, fastmath=_FAST)
def shade(Q, B, s_planes, best, imgs, sizes, sils, use_hull, centers, vcenter, G, method, d_bnd, k, gcam, fill,
          out_img, regions, primary):  # pragma: no cover - compiled
    """Colour of each virtual pixel at its chosen plane, by one of the four weightings.

    Q (N, 3, 3), B (N, 3) in camera order; imgs (N, Hm, Wm, 3) uint8; sizes (N, 2) int64 (W, H);
    sils (N, Hm, Wm) uint8; centers (N, 3), vcenter (3,), G (3, 3) float64 (virtual ray matrix); method: GLOBAL, NEAREST,
    ULR or KOJIMA; d_bnd (kojima), k (ulr: cameras blended), gcam (global: camera index); fill (3,)
    colour for pixels without depth. Writes out_img (h, w, 3) uint8, regions (h, w) uint8 (number of
    cameras with non-zero weight, 0 without depth) and primary (h, w) int16 (nearest camera or -1).
    Only the cameras that receive a weight are sampled.
    """
    N = Q.shape[0]
    h, w = best.shape
    for y in prange(h):
        cosv = np.empty(N)
        us = np.empty(N)
        vs = np.empty(N)
        cam = np.empty(N, np.int64)
        order = np.empty(N, np.int64)
        theta = np.empty(N)
        wts = np.empty(N)
        for x in range(w):
            j = best[y, x]
            m = 0
            if j >= 0:
                s = s_planes[j]
                z = 1.0 / s
                rx = z * (G[0, 0] * x + G[0, 1] * y + G[0, 2])
                ry = z * (G[1, 0] * x + G[1, 1] * y + G[1, 2])
                rz = z * (G[2, 0] * x + G[2, 1] * y + G[2, 2])
                rn = np.sqrt(rx * rx + ry * ry + rz * rz)
                for i in range(N):
                    hx = Q[i, 0, 0] * x + Q[i, 0, 1] * y + Q[i, 0, 2] + s * B[i, 0]
                    hy = Q[i, 1, 0] * x + Q[i, 1, 1] * y + Q[i, 1, 2] + s * B[i, 1]
                    hz = Q[i, 2, 0] * x + Q[i, 2, 1] * y + Q[i, 2, 2] + s * B[i, 2]
                    if hz <= _Z_MIN:
                        continue
                    u = hx / hz
                    v = hy / hz
                    if u < 0.0 or v < 0.0 or u > sizes[i, 0] - 1 or v > sizes[i, 1] - 1:
                        continue
                    if use_hull and sils[i, np.int64(v + 0.5), np.int64(u + 0.5)] == 0:
                        continue
                    dx = vcenter[0] + rx - centers[i, 0]
                    dy = vcenter[1] + ry - centers[i, 1]
                    dz = vcenter[2] + rz - centers[i, 2]
                    cosv[m] = (dx * rx + dy * ry + dz * rz) / (np.sqrt(dx * dx + dy * dy + dz * dz) * rn)
                    us[m] = u
                    vs[m] = v
                    cam[m] = i
                    m += 1
            if m == 0:
                out_img[y, x, 0] = fill[0]
                out_img[y, x, 1] = fill[1]
                out_img[y, x, 2] = fill[2]
                regions[y, x] = 0
                primary[y, x] = -1
                continue
            # order the visible cameras by decreasing cosine (insertion sort: m is small)
            for a in range(m):
                order[a] = a
            for a in range(1, m):
                key = order[a]
                b = a - 1
                while b >= 0 and cosv[order[b]] < cosv[key]:
                    order[b + 1] = order[b]
                    b -= 1
                order[b + 1] = key
            # weights of the sources, in order[:n]
            n = 1
            wts[0] = 1.0
            if method == KOJIMA and m >= 2:
                w1, w2 = kojima_weights(cosv[order[0]], cosv[order[1]], d_bnd)
                wts[0] = w1
                wts[1] = w2
                n = 2
            elif method == ULR and m >= 2:
                for a in range(m):
                    theta[a] = np.arccos(min(1.0, max(-1.0, cosv[order[a]])))
                n = ulr_weights(theta, m, k, wts)
            elif method == GLOBAL:
                for a in range(m):
                    if cam[a] == gcam:  # the global camera first; the nearest one when it cannot see
                        order[0] = a
            r0 = 0.0
            r1 = 0.0
            r2 = 0.0
            nreg = 0
            for a in range(n):
                wa = wts[a]
                if wa <= 0:
                    continue
                nreg += 1
                o = order[a]
                i = cam[o]
                u = us[o]
                v = vs[o]
                x0 = np.int64(u)
                y0 = np.int64(v)
                fx = u - x0
                fy = v - y0
                x1 = x0 + 1 if u < sizes[i, 0] - 1 else x0
                y1 = y0 + 1 if v < sizes[i, 1] - 1 else y0
                r0 += wa * _lerp2(np.float64(imgs[i, y0, x0, 0]), np.float64(imgs[i, y0, x1, 0]),
                                     np.float64(imgs[i, y1, x0, 0]), np.float64(imgs[i, y1, x1, 0]), fx, fy)
                r1 += wa * _lerp2(np.float64(imgs[i, y0, x0, 1]), np.float64(imgs[i, y0, x1, 1]),
                                     np.float64(imgs[i, y1, x0, 1]), np.float64(imgs[i, y1, x1, 1]), fx, fy)
                r2 += wa * _lerp2(np.float64(imgs[i, y0, x0, 2]), np.float64(imgs[i, y0, x1, 2]),
                                     np.float64(imgs[i, y1, x0, 2]), np.float64(imgs[i, y1, x1, 2]), fx, fy)
            out_img[y, x, 0] = np.uint8(min(255.0, max(0.0, r0 + 0.5)))
            out_img[y, x, 1] = np.uint8(min(255.0, max(0.0, r1 + 0.5)))
            out_img[y, x, 2] = np.uint8(min(255.0, max(0.0, r2 + 0.5)))
            regions[y, x] = nreg
            primary[y, x] = cam[order[0]] if method != GLOBAL else cam[_argmax(cosv, m)]


@njit(cache=True, inline="always")
def _argmax(a, m):  # pragma: no cover - compiled
    best = 0
    for i in range(1, m):
        if a[i] > a[best]:
            best = i
    return best


@njit(cache=True, parallel=True)
def refine_windows(coarse, h, w, radius, margin, n_planes, lo, hi):  # pragma: no cover - compiled
    """Per fine pixel (h, w), the plane window [min - margin, max + margin] of the valid coarse
    choices (coarse (hc, wc) int32, -1 invalid) within ``radius`` coarse pixels of its coarse
    parent (x // 2, y // 2), clipped to [0, n_planes - 1]; an empty window (lo > hi) where none is valid."""
    hc, wc = coarse.shape
    P_last = 1 << 30
    for y in prange(h):
        cy = min(y // 2, hc - 1)
        for x in range(w):
            cx = min(x // 2, wc - 1)
            mn = P_last
            mx = -1
            for yy in range(max(cy - radius, 0), min(cy + radius + 1, hc)):
                for xx in range(max(cx - radius, 0), min(cx + radius + 1, wc)):
                    b = coarse[yy, xx]
                    if b >= 0:
                        mn = min(mn, b)
                        mx = max(mx, b)
            if mx < 0:
                lo[y, x] = 1
                hi[y, x] = 0
            else:
                lo[y, x] = max(mn - margin, 0)
                hi[y, x] = min(mx + margin, n_planes - 1)
