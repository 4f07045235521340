"""Per-camera visibility of the rendered surface: z-buffers of the virtual view's own depth map.

The sweep colours a virtual pixel from the cameras that see its surface point inside their image (and
silhouette). A camera can still be blocked from that point by a nearer surface: in two-view
interpolation the background next to every foreground edge is hidden from one of the two sources
(disocclusion), and that camera's sample there is the foreground's colour. DIBR handles this with a
z-buffer per source; this module builds the same for the sweep, from the geometry the virtual view
itself sees.

:func:`splat_depths` forward-projects every virtual pixel that has a depth into each source camera and
keeps, per source pixel, the smallest camera depth that lands on it. Each point is written to the 2x2
source pixels around its projection, the four taps its colour would be sampled from
(:func:`workers.sweep.kernels.shade` samples bilinearly), so the buffer has no cracks where the virtual
view is sampled no more coarsely than the source (one virtual pixel spans at most about one source
pixel each way), and a point always finds itself among its own taps.

The colour kernel then treats camera ``i`` as seeing a pixel's point only if the point's depth in camera
``i`` is at most ``(1 + tolerance)`` times the smallest z-buffer depth over its four taps: a nearer
surface of the view covering any tap (the sample would mix in its colour) makes the camera not see it,
exactly like a camera whose image does not contain the point. The tolerance is relative, so it is
independent of the scene's units; it absorbs the depth change across a tap's footprint on slanted
surfaces.

A buffered surface counts as in front of the point only where, from camera ``i``, it has moved against the point by
at least :data:`workers.sweep.kernels.MIN_OCCLUDER_PARALLAX_PX` relative to where the view sees them both:
``f_i b_i (1/z_o - 1/z)`` px, with ``f_i`` the camera's focal length (px), ``b_i`` its distance from the view's
centre and ``z_o``, ``z`` the two depths along its axis. A nearer surface that has not moved lies beside the point
in the camera as it does in the view: a neighbour, caught by the 2x2 footprints at every depth edge (the background
pixel beside the foreground), not an occluder. Without the rule a camera at the view's own place, which sees exactly
the view's picture, was dropped there, and the occlusion fill's background pixels sit beside depth edges by
construction (-4 dB on the demo rig at a camera's place, up to -44 dB on wider rigs; benchmarks/RESULTS.md, the
viewer's quality levels).

Limits: only occluders that the virtual view itself sees are known (a surface outside the virtual
frustum, or hidden in the virtual view, cannot block a source here), and a source camera much closer to
the surface than the virtual one (one virtual pixel covering more than 2x2 of its pixels) gets
uncovered gaps in its buffer, where nothing is excluded.
"""
from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Iterator

import numpy as np
from numba import njit, prange

from .kernels import plane_point
from .layout import FAST as _FAST
from .layout import Z_MIN as _Z_MIN


@njit(cache=True, parallel=True, fastmath=_FAST, error_model="numpy")
def splat_depths(Q, B, s_pix, sizes, zbuf, zbox):  # pragma: no cover - compiled
    """Z-buffer of the virtual view's surface in every source camera.

    Q (N, 3, 3), B (N, 3) float64: the virtual-to-camera maps of :mod:`workers.sweep.kernels` (camera
    ``i`` sees virtual pixel (x, y) at inverse depth ``s`` at homogeneous pixel ``Q[i] @ (x, y, 1) + s
    B[i]``, whose third component divided by ``s`` is the point's depth along camera ``i``'s axis);
    s_pix (h, w) float64: each virtual pixel's inverse depth (1/m along the virtual axis), <= 0 where
    none; sizes (N, 2) int64: each camera's image (W, H) in px.

    Writes zbuf (N, Hm, Wm) float32, the smallest depth (m along camera ``i``'s axis) of the points that
    project within one pixel of each source pixel, inside each camera's box (the rest is left unwritten),
    and zbox (N, 4) int64, per camera that box u0, u1, v0, v1 (inclusive, px; u0 > u1 when empty): outside
    it the buffer holds nothing (no occluder). The box bounds the projections of the view's frustum between
    its nearest and farthest depth (the convex hull of that slab's 8 corners projects onto the hull of their
    projections), widened by a pixel for rounding; the whole image when a corner is behind the camera.
    A point counts for camera ``i`` when it is in front of it and projects inside its image
    (``0 <= u <= W-1``, ``0 <= v <= H-1``, the colour kernel's test); it is written to pixels
    floor(u)..floor(u)+1, floor(v)..floor(v)+1, clipped to the image (and to the box). Parallel over
    cameras (each thread owns one camera's buffer: no two threads write one pixel); allocates nothing.
    """
    N = Q.shape[0]
    h, w = s_pix.shape
    hm = zbuf.shape[1]
    wm = zbuf.shape[2]
    n_cam = min(N, zbuf.shape[0], zbox.shape[0], sizes.shape[0], B.shape[0])
    s_min = np.inf
    s_max = 0.0
    for y in range(h):
        for x in range(w):
            s = s_pix[y, x]
            if s > 0:
                s_min = min(s_min, s)
                s_max = max(s_max, s)
    for i in prange(n_cam):
        W = min(sizes[i, 0], wm)
        H = min(sizes[i, 1], hm)
        u0 = np.int64(0)
        u1 = np.int64(-1)
        v0 = np.int64(0)
        v1 = np.int64(-1)
        if s_max > 0 and W > 0 and H > 0:
            lo_u = np.inf
            hi_u = -np.inf
            lo_v = np.inf
            hi_v = -np.inf
            behind = False
            for corner in range(8):
                x = 0.0 if corner & 1 == 0 else float(w - 1)
                y = 0.0 if corner & 2 == 0 else float(h - 1)
                s = s_min if corner & 4 == 0 else s_max
                hz = Q[i, 2, 0] * x + Q[i, 2, 1] * y + Q[i, 2, 2] + s * B[i, 2]
                if not hz > _Z_MIN:
                    behind = True
                    break
                u = (Q[i, 0, 0] * x + Q[i, 0, 1] * y + Q[i, 0, 2] + s * B[i, 0]) / hz
                v = (Q[i, 1, 0] * x + Q[i, 1, 1] * y + Q[i, 1, 2] + s * B[i, 1]) / hz
                lo_u = min(lo_u, u)
                hi_u = max(hi_u, u)
                lo_v = min(lo_v, v)
                hi_v = max(hi_v, v)
            if behind:
                u1 = W - 1
                v1 = H - 1
            elif lo_u <= W and hi_u >= -1.0 and lo_v <= H and hi_v >= -1.0:
                u0 = max(np.int64(0), np.int64(np.floor(lo_u)) - 1)
                u1 = min(W - 1, np.int64(np.floor(hi_u)) + 2)
                v0 = max(np.int64(0), np.int64(np.floor(lo_v)) - 1)
                v1 = min(H - 1, np.int64(np.floor(hi_v)) + 2)
        zbox[i, 0] = u0
        zbox[i, 1] = u1
        zbox[i, 2] = v0
        zbox[i, 3] = v1
        for yy in range(v0, v1 + 1):
            for xx in range(u0, u1 + 1):
                zbuf[i, yy, xx] = np.inf
        if u0 > u1 or v0 > v1:
            continue
        for y in range(h):
            for x in range(w):
                s = s_pix[y, x]
                if not s > 0:
                    continue
                hz, u, v = plane_point(Q, B, i, x, y, s)
                if hz <= _Z_MIN:
                    continue
                if not (0.0 <= u <= W - 1 and 0.0 <= v <= H - 1):
                    continue
                xa = np.int64(u)  # floor: u >= 0
                ya = np.int64(v)
                xb = min(xa + 1, W - 1)
                yb = min(ya + 1, H - 1)
                if xa < u0 or xb > u1 or ya < v0 or yb > v1:
                    continue  # outside the box (only by rounding): not kept
                d = np.float32(hz / s)
                if d < zbuf[i, ya, xa]:
                    zbuf[i, ya, xa] = d
                if d < zbuf[i, ya, xb]:
                    zbuf[i, ya, xb] = d
                if d < zbuf[i, yb, xa]:
                    zbuf[i, yb, xa] = d
                if d < zbuf[i, yb, xb]:
                    zbuf[i, yb, xb] = d


def surface_zbuffers(Q: np.ndarray, B: np.ndarray, s_pix: np.ndarray, sizes: np.ndarray,
                     shape: tuple[int, int, int], out: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The z-buffers of :func:`splat_depths` for cameras of ``sizes`` (N, 2) int64 (W, H): zbuf
    ``shape`` = (N, Hm, Wm) float32 (m along each camera's axis; valid only inside each camera's box;
    written into ``out`` when given, a C-contiguous float32 array of that shape) and zbox (N, 4) int64
    (u0, u1, v0, v1 inclusive, px). Q (N, 3, 3), B (N, 3) float64, s_pix (h, w) float64 (1/m, <= 0 where
    no surface), as for the colour kernel."""
    n = Q.shape[0]
    if B.shape != (n, 3) or sizes.shape != (n, 2) or shape[0] != n:
        raise ValueError(f"camera tables disagree: Q {Q.shape}, B {B.shape}, sizes {sizes.shape}, buffers {shape}")
    if np.any(sizes[:, 0] > shape[2]) or np.any(sizes[:, 1] > shape[1]):
        raise ValueError(f"an image of sizes {sizes.tolist()} does not fit buffers of {shape[1:]} (H, W)")
    if out is None:
        out = np.empty(shape, np.float32)
    elif out.shape != tuple(shape) or out.dtype != np.float32 or not out.flags.c_contiguous:
        raise ValueError(f"out must be C-contiguous float32 of shape {tuple(shape)}, got {out.dtype} {out.shape}")
    zbox = np.empty((n, 4), np.int64)
    splat_depths(Q, B, np.ascontiguousarray(s_pix, np.float64), sizes, out, zbox)
    return out, zbox


class ZBufferStore:
    """One reusable z-buffer array of ``shape`` (N, Hm, Wm) float32 for a renderer: reusing it saves
    allocating (and page-faulting) N full camera images per render. A render that finds it taken by another
    thread's render gets a fresh array, so concurrent renders never share one."""

    def __init__(self, shape: tuple[int, int, int]) -> None:
        self.shape = tuple(shape)
        self._buf: np.ndarray | None = None
        self._lock = threading.Lock()

    @contextmanager
    def taken(self) -> Iterator[np.ndarray]:
        """The stored array while the ``with`` block runs (or a fresh one when it is in use)."""
        if not self._lock.acquire(blocking=False):
            yield np.empty(self.shape, np.float32)
            return
        try:
            if self._buf is None:
                self._buf = np.empty(self.shape, np.float32)
            yield self._buf
        finally:
            self._lock.release()
