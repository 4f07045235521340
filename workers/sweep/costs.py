"""Photo-consistency cost volumes: aggregation before the choice of a plane, and the choice itself.

One module for every depth search over planes (the sweep renderer's virtual views today, a dense
reconstruction tomorrow). Pure functions on numpy arrays; nothing here knows cameras.

Layout: a cost volume is (h, w, P) float32, pixel-major (a pixel's P plane costs are contiguous), plane
0 nearest. ``inf`` marks a plane that is not a candidate at that pixel (outside its search window, outside
the visual hull, or seen by too few cameras); a pixel whose every plane is ``inf`` has no surface.

The sweep's raw material is, per pixel and plane, ``ssd``: the sum over the voting cameras of the
squared distance of their (B, G, R) sample from the samples' mean (colour levels squared; the
per-pixel variance times the votes) and ``votes``: how many cameras voted. Both are additive over
pixels, so a window's sums are box filters and

    windowed variance(p, j) = sum_{q in W(p)} ssd(q, j) / sum_{q in W(p)} votes(q, j)

is exact (the vote-weighted mean of the pixels' variances; with a 1x1 window the per-pixel variance
that the winner-take-all search minimises). Pooling the colour sums themselves over the window would
measure the texture in the window, not the agreement between cameras, so the window sums the
per-pixel deviations instead.

Then, optionally, semi-global aggregation (Hirschmueller 2008) along 4 or 8 scanline directions with
penalties ``p1`` (a one-plane step) and ``p2`` (a larger jump), in the cost's units; then the winner
per pixel (ties to the nearer plane) and a parabola through the aggregated costs of its two neighbour
planes for a sub-plane position.
"""
from __future__ import annotations

import cv2
import numpy as np
from numba import njit, prange

CV_MAX_CHANNELS = 512  # cv2.boxFilter filters at most this many planes per call


def box_sum(volume: np.ndarray, radius: int) -> np.ndarray:
    """Sum over the (2 radius + 1)^2 window of every plane: (h, w, P) float32 -> (h, w, P) float32.

    Pixels beyond the border count as 0 (a window there sums what it covers). OpenCV's separable
    running-sum box filter, in chunks of at most 512 planes."""
    volume = np.ascontiguousarray(volume, np.float32)
    if radius <= 0:
        return volume.copy()
    k = (2 * radius + 1, 2 * radius + 1)
    out = np.empty_like(volume)
    P = volume.shape[2]
    for a in range(0, P, CV_MAX_CHANNELS):
        b = min(P, a + CV_MAX_CHANNELS)
        part = volume if (a, b) == (0, P) else np.ascontiguousarray(volume[:, :, a:b])
        out[:, :, a:b] = cv2.boxFilter(part, -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT).reshape(
            part.shape)
    return out


def windowed_variance(ssd: np.ndarray, votes: np.ndarray, radius: int) -> np.ndarray:
    """The windowed photo-consistency cost (h, w, P) float32 (colour levels squared; module docstring).

    ssd, votes: (h, w, P) float32 as the module docstring says (0 where a plane is not a candidate).
    radius: half the window side in pixels (0: the per-pixel variance). A plane stays a candidate at a
    pixel only where that pixel voted for it itself (``inf`` elsewhere), so a window never brings a
    plane into a pixel's search that its own window, hull or views ruled out."""
    num = box_sum(ssd, radius)
    den = box_sum(votes, radius)
    return _ratio(num, den, np.ascontiguousarray(votes, np.float32))


@njit(cache=True, parallel=True)
def _ratio(num, den, own):  # pragma: no cover - compiled
    h, w, P = num.shape
    out = np.empty((h, w, P), np.float32)
    for y in prange(h):
        for x in range(w):
            for j in range(P):
                out[y, x, j] = num[y, x, j] / den[y, x, j] if own[y, x, j] > 0 else np.inf
    return out


def robust_cost(variance: np.ndarray, cap: float) -> np.ndarray:
    """sqrt(variance) capped at ``cap`` (colour levels; ``inf`` stays ``inf``): (h, w, P) float32.

    The RMS deviation of the cameras' samples grows linearly with a colour mismatch, and the cap stops
    an occluded or specular pixel, which no plane explains, from dominating the aggregation."""
    return _capped_sqrt(np.ascontiguousarray(variance, np.float32), np.float32(cap))


@njit(cache=True, parallel=True)
def _capped_sqrt(v, cap):  # pragma: no cover - compiled
    h, w, P = v.shape
    out = np.empty((h, w, P), np.float32)
    for y in prange(h):
        for x in range(w):
            for j in range(P):
                c = v[y, x, j]
                out[y, x, j] = min(np.sqrt(c), cap) if c < np.inf else np.inf
    return out


def semi_global(cost: np.ndarray, p1: float, p2: float, directions: int = 4,
                windows: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Semi-global aggregation: (h, w, P) float32 cost -> (h, w, P) float32, the sum over the scanline
    directions r of

        L_r(p, j) = C(p, j) + min(L_r(p-r, j), L_r(p-r, j+-1) + p1, min_k L_r(p-r, k) + p2) - min_k L_r(p-r, k)

    p1, p2: penalties in the cost's units for a change of one plane and of more (p2 >= p1 >= 0).
    directions: 4 (left, right, up, down) or 8 (and the diagonals). ``inf`` planes stay ``inf``; a
    path restarts after a pixel with no candidate plane.

    windows: (lo, hi) (h, w) int32, each pixel's inclusive plane window (lo > hi: none) when the cost is ``inf``
    outside them (a coarse-to-fine level's narrow windows): the paths then visit only those planes, with the
    same result as over all P (an ``inf`` plane's L is ``inf``, and the minima run over the finite ones), in a
    fraction of the time; the total is ``inf`` outside them. None: every plane."""
    if directions not in (4, 8):
        raise ValueError(f"directions must be 4 or 8, got {directions}")
    if not 0.0 <= p1 <= p2:
        raise ValueError(f"needs 0 <= p1 <= p2, got p1={p1}, p2={p2}")
    cost = np.ascontiguousarray(cost, np.float32)
    h, w, P = cost.shape
    if windows is None:
        lo = np.zeros((h, w), np.int32)
        hi = np.full((h, w), P - 1, np.int32)
        total = np.zeros_like(cost)
    else:
        lo = np.ascontiguousarray(np.clip(windows[0], 0, P), np.int32)
        hi = np.ascontiguousarray(np.clip(windows[1], -1, P - 1), np.int32)
        if lo.shape != (h, w) or hi.shape != (h, w):
            raise ValueError(f"windows {lo.shape}, {hi.shape} do not match the cost's {(h, w)}")
        total = np.empty_like(cost)
        _window_totals(lo, hi, total)
    _rows(cost, lo, hi, np.float32(p1), np.float32(p2), total)
    steps = (0,) if directions == 4 else (0, -1, 1)
    for dx in steps:
        _columns(cost, lo, hi, np.float32(p1), np.float32(p2), np.int64(dx), total)
    return total


@njit(cache=True, parallel=True)
def _window_totals(lo, hi, total):  # pragma: no cover - compiled
    """total (h, w, P) float32: 0 inside each pixel's window lo..hi (h, w) int32, inf outside."""
    h, w, P = total.shape
    for y in prange(h):
        for x in range(w):
            for j in range(P):
                total[y, x, j] = 0.0 if lo[y, x] <= j <= hi[y, x] else np.inf


@njit(cache=True, inline="always")
def _path_step(c, prev, plo, phi, m, cur, total, lo, hi, p1, p2):  # pragma: no cover - compiled
    """One step of a path over the planes lo..hi of its pixel: cur from the cost c (P,) and the path's previous
    costs prev (P,), valid at its pixel's planes plo..phi (inf elsewhere), whose minimum is m (inf: the path
    starts here); adds cur to total (P,) and returns the minimum of cur."""
    out = np.inf
    if m == np.inf:
        for j in range(lo, hi + 1):
            cur[j] = c[j]
            total[j] += c[j]
            out = min(out, c[j])
        return out
    jump = m + p2
    for j in range(lo, hi + 1):
        best = jump
        if plo <= j <= phi:
            best = min(best, prev[j])
        if plo <= j - 1 <= phi:
            best = min(best, prev[j - 1] + p1)
        if plo <= j + 1 <= phi:
            best = min(best, prev[j + 1] + p1)
        v = c[j] + (best - m)
        cur[j] = v
        total[j] += v
        out = min(out, v)
    return out


@njit(cache=True, parallel=True, fastmath={"nsz", "contract", "reassoc"})
def _rows(cost, lo, hi, p1, p2, total):  # pragma: no cover - compiled
    """The left-to-right and right-to-left paths, one image row per work item."""
    h, w, P = cost.shape
    for y in prange(h):
        a = np.empty(P, np.float32)
        b = np.empty(P, np.float32)
        for direction in range(2):
            m = np.float32(np.inf)
            plo, phi = np.int64(1), np.int64(0)
            for k in range(w):
                x = k if direction == 0 else w - 1 - k
                prev, cur = (a, b) if k % 2 == 0 else (b, a)
                m = _path_step(cost[y, x], prev, plo, phi, m, cur, total[y, x], lo[y, x], hi[y, x], p1, p2)
                plo, phi = np.int64(lo[y, x]), np.int64(hi[y, x])


@njit(cache=True, inline="always")
def _path_start(s, h, w, dx, down):  # pragma: no cover - compiled
    """First pixel (y, x) of downward (or upward) path s with horizontal step dx: column s on the first
    row for s < w, else (diagonal) row s - w + 1 (counted from the first row) on the entering edge."""
    if s < w:
        return (np.int64(0) if down else np.int64(h - 1)), np.int64(s)
    off = np.int64(s - w + 1)
    return (off if down else np.int64(h - 1) - off), (np.int64(0) if dx > 0 else np.int64(w - 1))


@njit(cache=True, parallel=True, fastmath={"nsz", "contract", "reassoc"})
def _columns(cost, lo, hi, p1, p2, dx, total):  # pragma: no cover - compiled
    """The downward and upward paths with horizontal step dx (0: vertical, +-1: diagonal), one path per
    work item (:func:`_path_start`)."""
    h, w, P = cost.shape
    n_start = w if dx == 0 else w + h - 1
    for direction in range(2):
        down = direction == 0
        for s in prange(n_start):
            a = np.empty(P, np.float32)
            b = np.empty(P, np.float32)
            y, x = _path_start(s, h, w, dx, down)
            k = 0
            m = np.float32(np.inf)
            plo, phi = np.int64(1), np.int64(0)
            while 0 <= y < h and 0 <= x < w:
                prev, cur = (a, b) if k % 2 == 0 else (b, a)
                m = _path_step(cost[y, x], prev, plo, phi, m, cur, total[y, x], lo[y, x], hi[y, x], p1, p2)
                plo, phi = np.int64(lo[y, x]), np.int64(hi[y, x])
                y += 1 if down else -1
                x += dx
                k += 1


def winner(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The best plane per pixel and a sub-plane correction.

    cost (h, w, P) float32. Returns best (h, w) int32 (lowest cost, ties to the nearer plane; -1 where
    every plane is ``inf``), value (h, w) float32 (its cost; ``inf`` where none) and offset (h, w)
    float32 in [-0.5, 0.5] planes: the vertex of the parabola through the costs of planes best-1, best,
    best+1 (0 at the first and last plane, where a neighbour is not a candidate, or when the three are
    not convex)."""
    cost = np.ascontiguousarray(cost, np.float32)
    h, w, _ = cost.shape
    best = np.empty((h, w), np.int32)
    value = np.empty((h, w), np.float32)
    offset = np.empty((h, w), np.float32)
    _winner(cost, best, value, offset)
    return best, value, offset


@njit(cache=True, inline="always")
def parabola_vertex(c0: float, c1: float, c2: float) -> float:  # pragma: no cover - compiled
    """Abscissa in [-0.5, 0.5] of the vertex of the parabola through (-1, c0), (0, c1), (1, c2), where
    c1 is the smallest of the three; 0 when the curvature is not positive or a cost is not finite."""
    den = c0 - 2.0 * c1 + c2
    if not (den > 0.0 and den < np.inf):
        return 0.0
    return min(0.5, max(-0.5, 0.5 * (c0 - c2) / den))


@njit(cache=True, parallel=True)
def _winner(cost, best, value, offset):  # pragma: no cover - compiled
    h, w, P = cost.shape
    for y in prange(h):
        for x in range(w):
            bj = -1
            bc = np.inf
            for j in range(P):
                if cost[y, x, j] < bc:
                    bc = cost[y, x, j]
                    bj = j
            best[y, x] = bj
            value[y, x] = bc
            d = 0.0
            if 0 < bj < P - 1:
                d = parabola_vertex(float(cost[y, x, bj - 1]), float(bc), float(cost[y, x, bj + 1]))
            offset[y, x] = d


# ---------------------------------------------------------------------------------------------
# Costs that survive exposure changes (the dense reconstruction's; the renderer keeps the variance)
# ---------------------------------------------------------------------------------------------
def window_count(h: int, w: int, radius: int) -> np.ndarray:
    """(h, w) float32: how many pixels of the (2 radius + 1)^2 window around each pixel lie inside
    the h x w image (the window's size away from the border, fewer near it)."""
    ones = np.ones((h, w, 1), np.float32)
    return box_sum(ones, radius)[:, :, 0]


def zncc_cost(ref: np.ndarray, warped: np.ndarray, radius: int, min_std: float,
              valid: np.ndarray | None = None) -> np.ndarray:
    """Zero-mean normalised cross-correlation cost over a window: (h, w, P) float32, ``1 - ZNCC`` in [0, 2].

    ref (h, w) float32: the reference image (grey levels). warped (h, w, P) float32: another view's
    image resampled into the reference for each of P planes (finite everywhere: a caller clamps
    positions to the image so a window near its border still has samples). radius: half the window
    side in pixels; the window is cut at the image border (:func:`window_count` pixels). min_std: grey
    levels; where the reference window's standard deviation is below it the pixel has no cost (``inf``
    on every plane: a textureless window says nothing), where the warped window's is below it ZNCC
    counts as 0 (cost 1). valid (h, w, P) bool or None: False where the centre sample does not exist
    (outside that view's image or behind it): cost 1 there, a view that cannot vote neither helps nor
    hurts a plane.

    ZNCC is unchanged by any gain and offset of either image, so exposure and white-balance changes
    between frames do not move the minimum (the colour variance of the renderer is not)."""
    ref = np.ascontiguousarray(ref, np.float32)
    warped = np.ascontiguousarray(warped, np.float32)
    h, w, P = warped.shape
    if ref.shape != (h, w):
        raise ValueError(f"ref {ref.shape} and warped {warped.shape} differ in size")
    n = window_count(h, w, radius)[:, :, None].astype(np.float64)
    a = ref[:, :, None].astype(np.float64)
    sa = box_sum(ref[:, :, None], radius).astype(np.float64)
    saa = box_sum((a * a).astype(np.float32), radius).astype(np.float64)
    sb = box_sum(warped, radius).astype(np.float64)
    sbb = box_sum(warped * warped, radius).astype(np.float64)
    sab = box_sum(warped * ref[:, :, None], radius).astype(np.float64)
    va = saa - sa * sa / n
    vb = sbb - sb * sb / n
    floor = n * float(min_std) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (sab - sa * sb / n) / np.sqrt(va * vb)
    z = np.where(vb >= floor, np.clip(z, -1.0, 1.0), 0.0)
    cost = (1.0 - z).astype(np.float32)
    if valid is not None:
        cost[~np.asarray(valid, bool)] = 1.0
    cost[np.broadcast_to(va < floor, cost.shape)] = np.inf
    return cost


def best_k_mean(view_costs: np.ndarray, k: int) -> np.ndarray:
    """Combine per-view costs (V, h, w, P) float32 into (h, w, P) float32: the mean of the ``k``
    smallest of the V views' costs at each pixel and plane (all V when k >= V).

    Taking the best k of the neighbours, not all, lets a plane win where some neighbours do not see
    the surface (occlusion, leaving the image): their costs are simply not among the best. ``inf``
    (no cost at that pixel) stays ``inf``."""
    view_costs = np.asarray(view_costs, np.float32)
    V = view_costs.shape[0]
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    k = min(k, V)
    part = np.partition(view_costs, k - 1, axis=0)[:k] if k < V else view_costs
    return part.mean(axis=0, dtype=np.float64).astype(np.float32)

