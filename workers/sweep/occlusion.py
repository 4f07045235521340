"""Half-occlusions in the virtual view's depth: which pixels' plane the cameras' own views confirm, and a
background fill of the others (RenderOptions.occlusions).

Next to every depth edge of a view interpolated from two cameras lies a strip of background that one of
them cannot see (hidden behind the foreground, or outside its image at the frame's edge). No plane
explains both cameras' samples there, so the search's choice there is arbitrary: usually the foreground
spilling over the edge, or (at the frame's edge, where the true depth leaves one camera's image) a far
plane that both cameras happen to contain. Classic two-view stereo finds such pixels by a left-right
consistency check and gives them the farther of the neighbouring consistent depths along the scanline;
this module does the same for a virtual view and any number of cameras:

- :func:`view_winners` and :func:`confirmations`, the cross-view check. Every hypothesis (virtual
  pixel p, plane j) of the aggregated cost volume is a point that camera ``i`` sees at some pixel q. Seen
  from camera i, the hypotheses that land on q compete for q; the one of least cost wins it (camera i's
  own choice, from the same volume: the disparity-space cross-check of classic stereo, which needs no
  second search). Pixel p's chosen plane is *confirmed* by camera i when the winner of the pixel q it
  projects to is p itself (or a virtual pixel within ``tol_px`` of it). Where the foreground spills
  over a half-occluded strip, the cameras' pixels there are won by the background behind (or by the
  foreground's own pixels), so the spilled pixels lose their confirmations.
- :func:`background_fill`: each run of rejected pixels along a line (the image rows, or the columns
  when the cameras are spread vertically, :func:`fill_along_rows`) takes the plane of the farther of the
  two accepted pixels that bound it (the one when the run touches the border or a pixel without depth):
  a half-occluded strip is background by definition.

The colour of a filled pixel then comes from the cameras that see its (background) point, with
RenderOptions.visibility on.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from workers.camera import Camera

from .kernels import plane_point
from .layout import FAST as _FAST
from .layout import Z_MIN as _Z_MIN

CONFIRM_TOLERANCE_PX = 1
"""How far (px, each axis of the virtual view) a camera's winning virtual pixel may lie from a pixel and still confirm
its plane (:func:`confirmed_views`)."""


@njit(cache=True, parallel=True, fastmath=_FAST, error_model="numpy")
def view_winners(Q, B, s_planes, cost, lo, hi, sizes, win_cost, win_pix):  # pragma: no cover - compiled
    """Each camera's own choice among the virtual view's hypotheses.

    Q (N, 3, 3), B (N, 3) float64: the sweep's virtual-to-camera maps (:mod:`workers.sweep.kernels`);
    s_planes (P,) float64 inverse depths (1/m); cost (h, w, P) float32, the cost the planes were chosen
    on (``inf``: not a candidate); lo, hi (h, w) int32 the inclusive plane window of each pixel; sizes
    (N, 2) int64 each camera's (W, H).

    Writes, for every camera pixel (u, v) inside its image, win_cost[i, v, u] (float32, ``inf`` where no
    hypothesis lands) and win_pix[i, v, u] (int32, y * w + x of the winning virtual pixel, -1 where none):
    the least cost over the hypotheses (x, y, j) whose point camera ``i`` sees nearest to that pixel (in
    front of it, inside its image), ties to the first in row-major, nearest-plane-first order. Parallel over
    cameras (each owns its buffers); win_cost, win_pix are (N, Hm, Wm) with Hm, Wm >= every camera's size.
    """
    N = Q.shape[0]
    h, w, P = cost.shape
    for i in prange(N):
        W = sizes[i, 0]
        H = sizes[i, 1]
        for v in range(H):
            for u in range(W):
                win_cost[i, v, u] = np.inf
                win_pix[i, v, u] = -1
        for y in range(h):
            for x in range(w):
                j0 = max(np.int64(lo[y, x]), 0)
                j1 = min(np.int64(hi[y, x]), P - 1)
                for j in range(j0, j1 + 1):
                    c = cost[y, x, j]
                    if not c < np.inf:
                        continue
                    hz, u, v = plane_point(Q, B, i, x, y, s_planes[j])
                    if hz <= _Z_MIN or not (0.0 <= u <= W - 1 and 0.0 <= v <= H - 1):
                        continue
                    qu = np.int64(u + 0.5)
                    qv = np.int64(v + 0.5)
                    if c < win_cost[i, qv, qu]:
                        win_cost[i, qv, qu] = c
                        win_pix[i, qv, qu] = y * w + x


@njit(cache=True, parallel=True, fastmath=_FAST, error_model="numpy")
def confirmations(Q, B, s_planes, best, sizes, win_pix, tol_px, out):  # pragma: no cover - compiled
    """How many cameras confirm each virtual pixel's plane: out (h, w) uint8.

    best (h, w) int32: the chosen plane (-1: none, 0 confirmations); win_pix (N, Hm, Wm) int32 from
    :func:`view_winners`; tol_px: how far (px, in the virtual view, each axis) the winning virtual pixel
    may lie from the pixel itself. A camera counts when it sees the pixel's point at its plane (in front,
    inside the image) and the winner of its nearest pixel is within ``tol_px``; other arrays as
    :func:`view_winners`."""
    N = Q.shape[0]
    h, w = best.shape
    for y in prange(h):
        for x in range(w):
            j = best[y, x]
            n = 0
            if j >= 0:
                s = s_planes[j]
                for i in range(N):
                    hz, u, v = plane_point(Q, B, i, x, y, s)
                    if hz <= _Z_MIN or not (0.0 <= u <= sizes[i, 0] - 1 and 0.0 <= v <= sizes[i, 1] - 1):
                        continue
                    p = win_pix[i, np.int64(v + 0.5), np.int64(u + 0.5)]
                    if p >= 0 and abs(p // w - y) <= tol_px and abs(p % w - x) <= tol_px:
                        n += 1
            out[y, x] = min(n, 255)


def confirmed_views(Q: np.ndarray, B: np.ndarray, s_planes: np.ndarray, cost: np.ndarray, lo: np.ndarray,
                    hi: np.ndarray, best: np.ndarray, sizes: np.ndarray,
                    tol_px: int = CONFIRM_TOLERANCE_PX) -> np.ndarray:
    """The cross-view check (module docstring): (h, w) uint8, how many cameras' own choices confirm each
    pixel's plane ``best`` (h, w) int32. cost (h, w, P) float32 is the (aggregated) cost volume the planes
    were chosen on, ``inf`` where not a candidate, lo/hi (h, w) int32 its plane windows; Q (N, 3, 3), B (N, 3),
    s_planes (P,) float64 and sizes (N, 2) int64 (W, H) as for the sweep kernels."""
    n = Q.shape[0]
    hm, wm = int(sizes[:, 1].max()), int(sizes[:, 0].max())
    if cost.shape[:2] != best.shape or lo.shape != best.shape or hi.shape != best.shape:
        raise ValueError(f"cost {cost.shape}, lo {lo.shape}, hi {hi.shape} and best {best.shape} disagree")
    if best.size >= 2**31:
        raise ValueError("the view has too many pixels for int32 pixel indices")
    win_cost = np.empty((n, hm, wm), np.float32)
    win_pix = np.empty((n, hm, wm), np.int32)
    view_winners(Q, B, s_planes, np.ascontiguousarray(cost, np.float32), lo, hi, sizes, win_cost, win_pix)
    out = np.empty(best.shape, np.uint8)
    confirmations(Q, B, s_planes, best, sizes, win_pix, np.int64(tol_px), out)
    return out


@njit(cache=True, parallel=True)
def _fill_rows(best, offset, s_planes, bad):  # pragma: no cover - compiled
    """:func:`background_fill` along the rows, in place."""
    h, w = best.shape
    ds = (s_planes[-1] - s_planes[0]) / max(s_planes.shape[0] - 1, 1)
    for y in prange(h):
        x = 0
        while x < w:
            if not (bad[y, x] and best[y, x] >= 0):
                x += 1
                continue
            x1 = x
            while x1 < w and bad[y, x1] and best[y, x1] >= 0:
                x1 += 1
            # the pixels bounding the run, if they have a depth: the farther (smaller inverse depth) one wins
            src = -1
            s_src = np.inf
            for xx in (x - 1, x1):
                if 0 <= xx < w and best[y, xx] >= 0:
                    s = s_planes[best[y, xx]] + offset[y, xx] * ds
                    if s < s_src:
                        s_src = s
                        src = xx
            if src >= 0:
                for xx in range(x, x1):
                    best[y, xx] = best[y, src]
                    offset[y, xx] = offset[y, src]
            x = x1


def background_fill(best: np.ndarray, offset: np.ndarray, s_planes: np.ndarray, bad: np.ndarray,
                    rows: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The depth with every rejected pixel given the farther of its line's neighbouring accepted depths.

    best (h, w) int32 plane per pixel (-1: no depth), offset (h, w) float32 its sub-plane position (planes;
    the depth is at inverse depth s_planes[best] + offset * (s_planes[1] - s_planes[0])), s_planes (P,)
    float64 uniform inverse depths (1/m), bad (h, w) bool the rejected pixels. Along each row (``rows``) or
    column, a maximal run of rejected pixels that have a depth takes the plane and offset of whichever of
    the two pixels just outside the run is farther (smaller inverse depth), counting only pixels with a
    depth; of the one when only one exists; it keeps its own when neither does. Pixels without a depth stay
    without. Returns new (best, offset) arrays."""
    if not (best.shape == offset.shape == bad.shape):
        raise ValueError(f"best {best.shape}, offset {offset.shape} and bad {bad.shape} disagree")
    flip = (lambda a: a) if rows else np.transpose  # columns: the rows of the transposed arrays
    out_best = np.ascontiguousarray(flip(best), np.int32).copy()
    out_offset = np.ascontiguousarray(flip(offset), np.float32).copy()
    _fill_rows(out_best, out_offset, np.asarray(s_planes, np.float64), np.ascontiguousarray(flip(bad), np.bool_))
    return np.ascontiguousarray(flip(out_best)), np.ascontiguousarray(flip(out_offset))


def fill_along_rows(virtual: Camera, centers: np.ndarray) -> bool:
    """Whether half-occlusions run along the virtual view's rows: True when the cameras' centres (N, 3)
    (world, m) spread at least as far along its x axis as along its y axis (seen from the view, the
    disoccluded strips lie along the directions between cameras: horizontal for a horizontal rig)."""
    d = (np.asarray(centers, np.float64) - virtual.center) @ virtual.R.T  # in the view's axes
    return bool(np.ptp(d[:, 0]) >= np.ptp(d[:, 1]))
