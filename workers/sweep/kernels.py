"""Fused, compiled plane-sweep kernels (numba, parallel over bands of virtual image rows).

Geometry shared by the kernels: for virtual pixel (x, y) and plane ``j`` at inverse depth
``s = 1/z``, camera ``i`` sees the point at homogeneous pixel ``a_i(x, y) + s * B[i]`` with
``a_i = Q[i] @ (x, y, 1)``: ``Q[i] = M_i G`` and ``B[i] = M_i C_v + p_i`` for the camera's
``P_i = [M_i | p_i]``, the virtual centre ``C_v`` and ``G = R_v^T K_v^-1`` (the virtual ray
through (x, y) with unit depth). This is the plane-induced homography ``Q[i] + s B[i] e3^T`` in
a form that costs three multiply-adds per camera and plane.

A camera votes at a plane when the point is in front of it and projects inside its image
(``0 <= u <= W-1``, ``0 <= v <= H-1``: all four bilinear taps exist). With the visual hull on, a
point that projects inside some camera's image but outside its silhouette is outside the hull and
the plane is not tested for that pixel.

The depth search samples in fixed point: positions are rounded to 1/2**bits px (bits <= 6) and
each camera pixel is one uint64 holding B, G and R in 21-bit lanes (:func:`pack_images`), so one
bilinear blend of all three channels is three integer multiplies on the packed word ("SIMD within
a register"; lanes cannot overflow: 255 * 4**bits < 2**21). The samples are exact integers in units
of 4**-bits, so equal samples give exactly zero variance and sums of squares are exact in float64.
The search for the variance cost, the common one, runs 16 pixels at a time in vector instructions
(:mod:`workers.sweep.lanes`); the truncated cost and the colour pass run here, pixel by pixel, and so does
the variance search on request (the plain-numba search the lanes are measured against: same result).

The hot loops index arrays with unsigned integers (numba then skips the negative-index fix-up),
read per-camera parameters from flat tables with constant strides, and call no helper that takes
an array (numba would reference-count every such call).
"""
from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.extending import intrinsic

from .lanes import lane_depth_search
from .layout import BIG as _BIG
from .layout import CAM_F, CAM_I, MAX_BITS, TILE_COLS  # noqa: F401 - MAX_BITS: part of this module's interface
from .layout import FAST as _FAST
from .layout import SAFE as _SAFE
from .layout import Z_MIN as _Z_MIN
from .weighting import kojima_k_weights, kojima_weights, ulr_weights

GLOBAL, NEAREST, ULR, KOJIMA, KOJIMA_K = 0, 1, 2, 3, 4  # weighting.METHODS order
_LANE = np.uint64(21)
_LANE2 = np.uint64(42)
_LANE_MASK = np.uint64((1 << 21) - 1)
_U0 = np.uint64(0)
_U1 = np.uint64(1)
_U2 = np.uint64(2)
_U3 = np.uint64(3)
_U4, _U5, _U6, _U7, _U8, _U9, _U10, _U11 = (np.uint64(i) for i in range(4, 12))
_OUT = np.uint64(1 << 63)  # a position no image contains

_CF = np.uint64(CAM_F)
_CI = np.uint64(CAM_I)


@intrinsic
def _lrint(typingctx, x):  # pragma: no cover - compiled
    """float64 -> int64 rounded to nearest, ties to even, in one instruction (INT64_MIN when not
    representable), instead of rint followed by a truncating conversion."""
    if x != types.float64:
        return None

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.IntType(64), [ir.DoubleType()])
        fn = builder.module.declare_intrinsic("llvm.lrint", [ir.IntType(64), ir.DoubleType()], fnty)
        return builder.call(fn, args)

    return types.int64(types.float64), codegen


@njit(cache=True, inline="always", fastmath=_FAST, error_model="numpy")
def _position(ax, ay, az, bx, by, bz, s, scale):  # pragma: no cover - compiled
    """Pixel (u, v) of the homogeneous point (ax, ay, az) + s (bx, by, bz) and its fixed-point form
    (X, Y), uint64 in units of 1/scale px; X is out of any image when the point is behind the camera."""
    hz = az + s * bz
    inv = 1.0 / hz
    u = (ax + s * bx) * inv
    v = (ay + s * by) * inv
    X = np.uint64(_lrint(u * scale))
    Y = np.uint64(_lrint(v * scale))
    if hz <= _Z_MIN:
        X = _OUT
    return X, Y, u, v


@njit(cache=True, inline="always", fastmath=_FAST, error_model="numpy")
def plane_point(Q, B, i, x, y, s):  # pragma: no cover - compiled
    """Where camera ``i`` sees the virtual pixel (x, y) at inverse depth ``s`` (Q (N, 3, 3), B (N, 3) the
    sweep's per-camera homography and offset): (hz, u, v), hz the point's depth in camera i over the
    virtual one's, (u, v) its pixel; (u, v) mean nothing unless hz > Z_MIN (in front of the camera)."""
    hz = Q[i, 2, 0] * x + Q[i, 2, 1] * y + Q[i, 2, 2] + s * B[i, 2]
    inv = 1.0 / hz
    u = (Q[i, 0, 0] * x + Q[i, 0, 1] * y + Q[i, 0, 2] + s * B[i, 0]) * inv
    v = (Q[i, 1, 0] * x + Q[i, 1, 1] * y + Q[i, 1, 2] + s * B[i, 1]) * inv
    return hz, u, v


MIN_OCCLUDER_PARALLAX_PX = 0.5
"""How far (px) a nearer surface of the view must have moved against a point, seen from a camera, to hide the point
from it (:func:`unhidden`, :mod:`workers.sweep.visibility`)."""


@njit(cache=True, inline="always", fastmath=_FAST, error_model="numpy")
def unhidden(zbuf, zbox, i, u, v, W, H, depth, scale, parallax):  # pragma: no cover - compiled
    """Whether camera ``i`` sees the point at its pixel (u, v) (inside its W x H image) and ``depth`` (m along its
    axis) past the z-buffered surface of :mod:`workers.sweep.visibility` (zbuf (N, Hm, Wm) float32, zbox (N, 4)
    int64): no buffered depth z_o over the four pixels its colour is sampled from with depth > scale x z_o and
    parallax x (1/z_o - 1/depth) >= :data:`MIN_OCCLUDER_PARALLAX_PX` (``parallax``: the camera's focal length (px)
    times its distance from the view's centre (m); nothing buffered outside the camera's box)."""
    xa = np.int64(u)
    ya = np.int64(v)
    xb = xa + 1 if u < W - 1 else xa
    yb = ya + 1 if v < H - 1 else ya
    if not (zbox[i, 0] <= xa and xb <= zbox[i, 1] and zbox[i, 2] <= ya and yb <= zbox[i, 3]
            and yb < zbuf.shape[1] and xb < zbuf.shape[2]):
        return True
    for zo in (zbuf[i, ya, xa], zbuf[i, ya, xb], zbuf[i, yb, xa], zbuf[i, yb, xb]):
        if depth > zo * scale and parallax * (1.0 / zo - 1.0 / depth) >= MIN_OCCLUDER_PARALLAX_PX:
            return False
    return True


@njit(cache=True, inline="always")
def _bilinear(p00, p01, p10, p11, fx, fy, ub):  # pragma: no cover - compiled
    """Bilinear blend of four packed pixels with fixed-point weights fx, fy in [0, 2**ub): the three
    channels as float64 in units of 4**-ub. Wrap-around of the differences cancels (the result's
    lanes are in range), so the packed arithmetic is exact."""
    top = (p00 << ub) + (p01 - p00) * fx
    bot = (p10 << ub) + (p11 - p10) * fx
    val = (top << ub) + (bot - top) * fy
    return float(val & _LANE_MASK), float((val >> _LANE) & _LANE_MASK), float(val >> _LANE2)


@njit(cache=True, parallel=True)
def pack_images(imgs, sizes, out):  # pragma: no cover - compiled
    """imgs (N, Hm, Wm, 3) uint8 BGR, sizes (N, 2) int64 (W, H) -> out (N, Hm + 1, Wm + 1) uint64
    with ``B | G << 21 | R << 42`` per pixel and zeros outside each image (the extra row and column
    keep the bilinear taps of the last row and column inside the array)."""
    n, hp, wp = out.shape
    for k in prange(n * hp):
        i = k // hp
        y = k % hp
        w = sizes[i, 0]
        h = sizes[i, 1]
        for x in range(wp):
            v = _U0
            if y < h and x < w:
                v = (np.uint64(imgs[i, y, x, 0]) | (np.uint64(imgs[i, y, x, 1]) << _LANE)
                     | (np.uint64(imgs[i, y, x, 2]) << _LANE2))
            out[i, y, x] = v


def _pixel_search(use_hull: bool, truncated: bool):
    """:func:`sweep_depth` pixel by pixel, compiled for one visual-hull setting and one cost (truncated or
    not). Both are constants of the compiled code, so that its hot loop tests neither (fewer instructions and
    cycles than testing them at run time). The variance cost is pruned exactly (see :mod:`workers.sweep.lanes`); the truncated cost has no
    bound from a subset of the cameras and is not."""

    @njit(cache=True, parallel=True, fastmath=_FAST, error_model="numpy")
    def search(camf, cami, pix, silflat, min_views, trunc2, bits, s_planes, lo, hi, bands, band_h, best,
               best_cost):  # pragma: no cover - compiled
        n_cam = cami.shape[0] // CAM_I
        un = np.uint64(n_cam)
        h, w = best.shape
        ub = np.uint64(bits)
        fmask = (_U1 << ub) - _U1
        scale = float(1 << bits)
        inv_s4 = 1.0 / scale**4  # samples are in units of 2**-2bits, squares in 2**-4bits
        t2 = trunc2 * scale**4
        # n (n + cameras after m), the pruning bound's factor, at m * (n_cam + 1) + n (n <= m + 1 votes after camera m)
        votes_bound = np.zeros(n_cam * (n_cam + 1))
        for m in range(n_cam):
            for n in range(m + 2):
                votes_bound[m * (n_cam + 1) + n] = float(n * (n + n_cam - 1 - m))
        row_vb = np.uint64(n_cam + 1)
        for k in prange(bands.shape[0]):
            A = np.empty(3 * n_cam)  # a_i(x, y) of every camera for the current pixel
            smp = np.empty(3 * n_cam)
            first = _U0  # the camera that culled last is tried first: it usually culls again
            y_a = bands[k] * band_h
            rows = min(band_h, h - y_a)
            # the band tile by tile (rows within a tile), so that the cameras' data is reused from cache
            for tr in range(rows * (-(-w // TILE_COLS))):
                x_a = (tr // rows) * TILE_COLS
                y = y_a + tr % rows
                yf = float(y)
                for x in range(x_a, min(x_a + TILE_COLS, w)):
                    left = np.int64(best[y, x - 1]) if x > 0 else -1
                    up = np.int64(best[y - 1, x]) if y > y_a else -1
                    j0 = np.int64(lo[y, x])
                    j1 = np.int64(hi[y, x])
                    bc = _BIG
                    bc_safe = _BIG * _SAFE  # bc widened for the pruning test
                    bj = -1
                    xf = float(x)
                    for m in range(un if j0 <= j1 else _U0):
                        f = m * _CF
                        A[_U3 * m] = camf[f] * xf + camf[f + _U1] * yf + camf[f + _U2]
                        A[_U3 * m + _U1] = camf[f + _U3] * xf + camf[f + _U4] * yf + camf[f + _U5]
                        A[_U3 * m + _U2] = camf[f + _U6] * xf + camf[f + _U7] * yf + camf[f + _U8]
                    g1 = left if j0 <= left <= j1 else -1
                    g2 = up if j0 <= up <= j1 and up != g1 else -1
                    for jj in range(j0 - 2, j1 + 1):
                        if jj == j0 - 2:
                            j = g1
                        elif jj == j0 - 1:
                            j = g2
                        else:
                            j = jj if jj != g1 and jj != g2 else -1
                        if j < 0:
                            continue
                        s = s_planes[j]
                        if use_hull:
                            # the camera that culled last usually culls again: a quick look at it first
                            f = first * _CF
                            X, Y, u, v = _position(A[_U3 * first], A[_U3 * first + _U1], A[_U3 * first + _U2],
                                                   camf[f + _U9], camf[f + _U10], camf[f + _U11], s, scale)
                            c = first * _CI
                            if X <= np.uint64(cami[c]) and Y <= np.uint64(cami[c + _U1]):
                                o = np.uint64(cami[c + _U4]) + np.uint64(_lrint(v)) * np.uint64(cami[c + _U5])
                                if silflat[o + np.uint64(_lrint(u))] == 0:
                                    continue
                        # camera by camera: sample and score, abandoning the plane once it cannot win (and, with
                        # the hull, once a camera sees the point outside its silhouette)
                        s0 = 0.0
                        s1 = 0.0
                        s2 = 0.0
                        q = 0.0
                        n = 0
                        dropped = False
                        for m in range(un):
                            f = m * _CF
                            X, Y, u, v = _position(A[_U3 * m], A[_U3 * m + _U1], A[_U3 * m + _U2], camf[f + _U9],
                                                   camf[f + _U10], camf[f + _U11], s, scale)
                            c = m * _CI
                            if X > np.uint64(cami[c]) or Y > np.uint64(cami[c + _U1]):
                                continue
                            if use_hull:
                                # the silhouette pixel nearest to the exact position, as the colour kernel takes it
                                o = np.uint64(cami[c + _U4]) + np.uint64(_lrint(v)) * np.uint64(cami[c + _U5])
                                if silflat[o + np.uint64(_lrint(u))] == 0:
                                    dropped = True
                                    first = m
                                    break
                            row = np.uint64(cami[c + _U3])
                            o = np.uint64(cami[c + _U2]) + (Y >> ub) * row + (X >> ub)
                            c0, c1, c2 = _bilinear(pix[o], pix[o + _U1], pix[o + row], pix[o + row + _U1], X & fmask,
                                                   Y & fmask, ub)
                            s0 += c0
                            s1 += c1
                            s2 += c2
                            q += c0 * c0 + c1 * c1 + c2 * c2
                            if truncated:
                                smp[3 * n] = c0
                                smp[3 * n + 1] = c1
                                smp[3 * n + 2] = c2
                            n += 1
                            if not truncated and n >= 2:
                                # SSD of the n samples so far <= n_all x cost, n_all <= n + cameras left: prune
                                # when SSD > n_all x best (>= for a farther plane, which loses ties), in the
                                # division-free form n SSD > n n_all best; lhs is exact, rhs rounded up
                                lhs = n * q - (s0 * s0 + s1 * s1 + s2 * s2)
                                rhs = bc_safe * votes_bound[m * row_vb + np.uint64(n)]
                                if lhs >= rhs and (lhs > rhs or j > bj):
                                    dropped = True
                                    break
                        if dropped or n < min_views:
                            continue
                        if truncated:
                            m0 = s0 / n
                            m1 = s1 / n
                            m2 = s2 / n
                            cost = 0.0
                            for t in range(n):
                                dev = (smp[3 * t] - m0) ** 2 + (smp[3 * t + 1] - m1) ** 2 + (smp[3 * t + 2] - m2) ** 2
                                cost += min(dev, t2)
                            cost /= n
                        else:
                            cost = (n * q - (s0 * s0 + s1 * s1 + s2 * s2)) / (n * n)
                        if cost < bc or (cost == bc and j < bj):
                            bc = cost
                            bc_safe = cost * _SAFE
                            bj = j
                    best[y, x] = bj
                    best_cost[y, x] = bc * inv_s4 if bj >= 0 else np.inf

    return search


_PIXEL_SEARCHES = {(hull, trunc): _pixel_search(hull, trunc) for hull in (False, True) for trunc in (False, True)}


def sweep_depth(camf, cami, pix, silflat, use_hull, min_views, trunc2, bits, s_planes, lo, hi, bands, band_h,
                best, best_cost, lanes: bool = True) -> None:
    """Most photo-consistent plane per virtual pixel.

    camf (N * CAM_F,) float64 and cami (N * CAM_I,) int64: per-camera rows in sampling order; see
    CAM_F / CAM_I. pix: all packed images (:func:`pack_images`), flattened; silflat: all silhouettes,
    uint8, flattened (used when ``use_hull``). trunc2 > 0 selects the truncated cost
    ``mean_i min(|c_i - mean|^2, trunc2)``, else the variance summed over channels. bits: sampling
    positions are multiples of 2**-bits px (1..MAX_BITS; 5 gives OpenCV's warp positions). s_planes (P,)
    inverse depths; lo, hi (h, w) int32: inclusive plane window per pixel. bands (nb,) int64: row bands
    of ``band_h`` rows in the order the threads take them (interleaved, so that each thread gets work from
    the whole view); a band is swept in tiles of TILE_COLS columns. Writes best (h, w) int32 (-1: no
    plane with >= min_views votes inside the hull) and best_cost (h, w) float32 (inf where best is -1).
    Ties go to the nearer plane (smaller index).

    The variance cost runs in :mod:`workers.sweep.lanes` (16 pixels per vector instruction, exact
    pruning) unless ``lanes`` is False; the truncated cost, and the variance cost with ``lanes=False``, run
    here pixel by pixel. Both searches give the same result.
    """
    if trunc2 <= 0 and lanes:
        lane_depth_search(camf, cami, pix, silflat, use_hull, min_views, bits, s_planes, lo, hi, bands, band_h, best,
                          best_cost)
        return
    _PIXEL_SEARCHES[bool(use_hull), trunc2 > 0](camf, cami, pix, silflat, min_views, trunc2, bits, s_planes, lo, hi,
                                                bands, band_h, best, best_cost)


@njit(cache=True, inline="always", fastmath=_FAST)
def _lerp2(a, b, c, d, fx, fy):  # pragma: no cover - compiled
    """Bilinear blend of a (top-left), b (top-right), c (bottom-left), d (bottom-right), written as
    nested lerps so that a uniform patch gives its value exactly."""
    top = a + fx * (b - a)
    bot = c + fx * (d - c)
    return top + fy * (bot - top)


@njit(cache=True, parallel=True, fastmath=_FAST, error_model="numpy")
def shade(Q, B, s_pix, imgs, sizes, sils, use_hull, centers, vcenter, G, method, d_bnd, k, gcam, fill,
          out_img, regions, primary, weights, zbuf, zbox, vis_tol, vis_mask, parallax):  # pragma: no cover - compiled
    """Colour of each virtual pixel at its chosen depth, by one of the five weightings.

    Q (N, 3, 3), B (N, 3) in camera order; s_pix (h, w) float64: each pixel's inverse depth (1/m along
    the virtual axis; a plane's, or between planes after sub-plane refinement), <= 0 where none; imgs (N, Hm, Wm, 3) uint8; sizes (N, 2) int64 (W, H);
    sils (N, Hm, Wm) uint8; centers (N, 3), vcenter (3,), G (3, 3) float64 (virtual ray matrix); method: GLOBAL, NEAREST,
    ULR, KOJIMA or KOJIMA_K; d_bnd (kojima, kojima_k), k (ulr: cameras blended), gcam (global: camera
    index); fill (3,) colour for pixels without depth. Writes out_img (h, w, 3) uint8, regions (h, w)
    uint8 (number of cameras with non-zero weight, 0 without depth) and primary (h, w) int16 (nearest
    camera or -1); and, when ``weights`` is (h, w, N) float32 rather than empty ((0, 0, 0)), each
    camera's weight at each pixel (0 for cameras not blended and pixels without depth).
    Only the cameras that receive a weight are sampled.

    Visibility (on when zbuf is (N, Hm, Wm) float32 rather than empty (0, 0, 0)): zbuf, zbox (N, 4) int64
    are the z-buffers of the view's own surface in each camera (:mod:`workers.sweep.visibility`; depth in m
    along the camera's axis, valid inside box u0, u1, v0, v1). A camera whose image contains the point
    is dropped when the point's depth in it exceeds (1 + vis_tol) times a buffered depth at the four pixels its
    colour would be sampled from, that surface having moved against the point by a pixel's fraction or more
    (:func:`unhidden`, parallax (N,) float64: each camera's focal length times its distance from vcenter): it
    then takes no part, exactly as a camera whose image does not contain the point. When that drops
    every camera that sees the point, all of them take part (no new holes). vis_mask (h, w) bool limits the
    test to its True pixels (the occlusion fill's pixels, RenderOptions.visibility None); empty (0, 0): every
    pixel.
    """
    N = Q.shape[0]
    h, w = s_pix.shape
    want_w = weights.shape[0] > 0
    # cameras ranked per pixel: the nearest for nearest/global/kojima_k, two for kojima, k + 1 for ulr (threshold)
    n_rank = 2 if method == KOJIMA else (min(k + 1, N) if method == ULR else 1)
    use_vis = zbuf.shape[0] > 0 and zbuf.shape[0] >= N and zbox.shape[0] >= N and zbox.shape[1] >= 4
    vis_scale = 1.0 + vis_tol
    masked = vis_mask.shape[0] > 0
    for y in prange(h):
        seen = np.empty(N, np.bool_)  # visibility: no nearer surface of the view in front of the point
        cosv = np.empty(N)
        us = np.empty(N)
        vs = np.empty(N)
        cam = np.empty(N, np.int64)
        order = np.empty(N, np.int64)
        theta = np.empty(N)
        wts = np.empty(N)
        for x in range(w):
            s = s_pix[y, x]
            m = 0
            vis_here = use_vis and (not masked or vis_mask[y, x])
            if s > 0:
                z = 1.0 / s
                rx = z * (G[0, 0] * x + G[0, 1] * y + G[0, 2])
                ry = z * (G[1, 0] * x + G[1, 1] * y + G[1, 2])
                rz = z * (G[2, 0] * x + G[2, 1] * y + G[2, 2])
                inv_rn = 1.0 / np.sqrt(rx * rx + ry * ry + rz * rz)
                for i in range(N):
                    hz, u, v = plane_point(Q, B, i, x, y, s)
                    if hz <= _Z_MIN:
                        continue
                    if not (0.0 <= u <= sizes[i, 0] - 1 and 0.0 <= v <= sizes[i, 1] - 1):
                        continue
                    if use_hull and sils[i, np.uint64(_lrint(v)), np.uint64(_lrint(u))] == 0:
                        continue
                    dx = vcenter[0] + rx - centers[i, 0]
                    dy = vcenter[1] + ry - centers[i, 1]
                    dz = vcenter[2] + rz - centers[i, 2]
                    cosv[m] = (dx * rx + dy * ry + dz * rz) * inv_rn / np.sqrt(dx * dx + dy * dy + dz * dz)
                    us[m] = u
                    vs[m] = v
                    cam[m] = i
                    if vis_here:  # the point's depth along camera i: hz / s
                        seen[m] = unhidden(zbuf, zbox, i, u, v, sizes[i, 0], sizes[i, 1], hz * z, vis_scale,
                                           parallax[i])
                    m += 1
            if vis_here and m > 1:
                # keep only the cameras nothing of the view hides the point from (in camera order, as if the
                # others' images did not contain it); all of them when none is left
                nv = 0
                for a in range(m):
                    if seen[a]:
                        cosv[nv] = cosv[a]
                        us[nv] = us[a]
                        vs[nv] = vs[a]
                        cam[nv] = cam[a]
                        nv += 1
                if nv > 0:
                    m = nv
            if m == 0:
                out_img[y, x, 0] = fill[0]
                out_img[y, x, 1] = fill[1]
                out_img[y, x, 2] = fill[2]
                regions[y, x] = 0
                primary[y, x] = -1
                if want_w:
                    for i in range(N):
                        weights[y, x, i] = 0.0
                continue
            # the n_rank visible cameras of largest cosine, in decreasing order (partial selection sort)
            for a in range(m):
                order[a] = a
            r = min(n_rank, m)
            for a in range(r):
                bi = a
                for b in range(a + 1, m):
                    if cosv[order[b]] > cosv[order[bi]]:
                        bi = b
                tmp = order[a]
                order[a] = order[bi]
                order[bi] = tmp
            nearest = order[0]
            # weights of the sources, in order[:n]
            n = 1
            wts[0] = 1.0
            if method == KOJIMA and m >= 2:
                w1, w2 = kojima_weights(cosv[order[0]], cosv[order[1]], d_bnd)
                wts[0] = w1
                wts[1] = w2
                n = 2
            elif method == ULR and m >= 2:
                for a in range(r):
                    theta[a] = np.arccos(min(1.0, max(-1.0, cosv[order[a]])))
                n = ulr_weights(theta, r, k, wts)
            elif method == KOJIMA_K and m >= 2:
                # eq. (6k): every visible camera within d_bnd of the primary's cosine, in visibility order
                kojima_k_weights(cosv, m, d_bnd, wts)
                for a in range(m):
                    order[a] = a
                n = m
            elif method == GLOBAL:
                for a in range(m):
                    if cam[a] == gcam:  # the global camera first; the nearest one when it cannot see
                        order[0] = a
            r0 = 0.0
            r1 = 0.0
            r2 = 0.0
            nreg = 0
            if want_w:
                for i in range(N):
                    weights[y, x, i] = 0.0
            for a in range(n):
                wa = wts[a]
                if wa <= 0:
                    continue
                nreg += 1
                o = order[a]
                if want_w:
                    weights[y, x, cam[o]] = wa
                i = np.uint64(cam[o])
                u = us[o]
                v = vs[o]
                x0 = np.uint64(u)
                y0 = np.uint64(v)
                fx = u - float(x0)
                fy = v - float(y0)
                x1 = x0 + _U1 if u < sizes[i, 0] - 1 else x0
                y1 = y0 + _U1 if v < sizes[i, 1] - 1 else y0
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
            primary[y, x] = cam[nearest]


@njit(cache=True, parallel=True, fastmath=_FAST, error_model="numpy")
def hull_windows(Q, B, bounds, s_planes, lo, hi):  # pragma: no cover - compiled
    """Narrow each pixel's plane window lo..hi (h, w) int32, in place, to the planes whose point
    projects inside the bounding box of every camera's silhouette: a cheap, conservative first cut of
    the visual hull (the sweep still tests the silhouettes themselves). Only cameras whose image
    contains the pixel's whole ray segment take part (elsewhere a camera does not vote, so it does
    not cull either).

    Q (N, 3, 3), B (N, 3) (module docstring); bounds (N, 6) float64 per camera: W - 1, H - 1 and the
    box u0, u1, v0, v1 in px, widened by half a pixel for the nearest-pixel silhouette lookup (u0 > u1
    for an empty silhouette); s_planes (P,) inverse depths, uniform (np.linspace). Along the ray each
    box side is a linear condition on the inverse depth s, so the allowed planes form one interval.
    """
    N = Q.shape[0]
    h, w = lo.shape
    P = s_planes.shape[0]
    s_first = s_planes[0]
    ds = (s_planes[0] - s_planes[P - 1]) / (P - 1)  # > 0: s falls with the plane index
    for y in prange(h):
        for x in range(w):
            j0 = lo[y, x]
            j1 = hi[y, x]
            if j0 > j1:
                continue
            s_hi = s_planes[j0]
            s_lo = s_planes[j1]
            for i in range(N):
                ax = Q[i, 0, 0] * x + Q[i, 0, 1] * y + Q[i, 0, 2]
                ay = Q[i, 1, 0] * x + Q[i, 1, 1] * y + Q[i, 1, 2]
                az = Q[i, 2, 0] * x + Q[i, 2, 1] * y + Q[i, 2, 2]
                bx = B[i, 0]
                by = B[i, 1]
                bz = B[i, 2]
                z_a = az + s_lo * bz
                z_b = az + s_hi * bz
                if z_a <= _Z_MIN or z_b <= _Z_MIN:
                    continue
                u_a = (ax + s_lo * bx) / z_a
                v_a = (ay + s_lo * by) / z_a
                u_b = (ax + s_hi * bx) / z_b
                v_b = (ay + s_hi * by) / z_b
                if not (0.0 <= u_a <= bounds[i, 0] and 0.0 <= u_b <= bounds[i, 0]
                        and 0.0 <= v_a <= bounds[i, 1] and 0.0 <= v_b <= bounds[i, 1]):
                    continue
                for side in range(4):
                    # the condition c + s d >= 0 of one box side (hz > 0 on the whole segment)
                    if side == 0:
                        c = ax - bounds[i, 2] * az
                        d = bx - bounds[i, 2] * bz
                    elif side == 1:
                        c = bounds[i, 3] * az - ax
                        d = bounds[i, 3] * bz - bx
                    elif side == 2:
                        c = ay - bounds[i, 4] * az
                        d = by - bounds[i, 4] * bz
                    else:
                        c = bounds[i, 5] * az - ay
                        d = bounds[i, 5] * bz - by
                    if d > 0:
                        s_lo = max(s_lo, -c / d)
                    elif d < 0:
                        s_hi = min(s_hi, -c / d)
                    elif c < 0:
                        s_lo = np.inf
                if not s_lo <= s_hi:
                    break
            if not s_lo <= s_hi:
                lo[y, x] = 1
                hi[y, x] = 0
            else:
                # one plane more on each side covers rounding in the index arithmetic
                lo[y, x] = max(j0, np.int64(np.floor((s_first - s_hi) / ds)))
                hi[y, x] = min(j1, np.int64(np.ceil((s_first - s_lo) / ds)))


@njit(cache=True, parallel=True)
def refine_windows(coarse, h, w, radius, margin, n_planes, lo, hi):  # pragma: no cover - compiled
    """Per fine pixel (h, w), the plane window [min - margin, max + margin] of the valid coarse
    choices (coarse (hc, wc) int32, -1 invalid) within ``radius`` coarse pixels of its coarse
    parent (x // 2, y // 2), clipped to [0, n_planes - 1]; an empty window (lo > hi) where none is valid."""
    hc, wc = coarse.shape
    mn = np.empty((hc, wc), np.int64)  # per coarse pixel, over its neighbourhood (each is shared by 4 fine pixels)
    mx = np.empty((hc, wc), np.int64)
    for cy in prange(hc):
        for cx in range(wc):
            a = n_planes
            b = -1
            for yy in range(max(cy - radius, 0), min(cy + radius + 1, hc)):
                for xx in range(max(cx - radius, 0), min(cx + radius + 1, wc)):
                    v = coarse[yy, xx]
                    if v >= 0:
                        a = min(a, v)
                        b = max(b, v)
            mn[cy, cx] = a
            mx[cy, cx] = b
    for y in prange(h):
        cy = min(y // 2, hc - 1)
        for x in range(w):
            cx = min(x // 2, wc - 1)
            if mx[cy, cx] < 0:
                lo[y, x] = 1
                hi[y, x] = 0
            else:
                lo[y, x] = max(mn[cy, cx] - margin, 0)
                hi[y, x] = min(mx[cy, cx] + margin, n_planes - 1)
