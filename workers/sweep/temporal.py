"""Temporal consistency of the chosen depth: a view drawn again from the same viewpoint on a newer frame set keeps
its previous depth wherever the scene did not move.

Where nothing moves, a frame set repeats the last one's pixels, yet a new depth search can still choose another
plane: a weakly textured pixel, or one with several planes nearly as good, is decided by samples along its whole
search range, and a moving object that crosses some camera's epipolar segment of it (or the semi-global paths
through it, or a visual-hull window it changes) tips the choice. The picture then flickers where nothing moved
(benchmarks/RESULTS.md, section sweep, "Flicker on the demo recording").

- :class:`ChangeTracker`: per camera pixel, the number of the frame set in which it last changed by more than
  ``still_levels`` in a channel, against its value at that change (noise and slow drift below the threshold never
  add up to a change of their own making, and a change is seen however many sets it took).
- :meth:`ChangeTracker.still_pixels`: which pixels of a previous render still show a scene that did not move: the
  cameras nearest to the view at the pixel's point (at its depth), those its colour comes from, sample it from camera
  pixels unchanged since that render's frame set. A camera farther round may well see a change there (a moving
  object passing in front of the point from its side) without the point having moved; an object arriving in the
  view's line of sight changes what the nearest cameras see too. The renderer keeps the previous depth at these
  pixels (:meth:`workers.sweep.renderer.SweepRenderer.render`, ``previous``).
"""
from __future__ import annotations

import itertools

import numpy as np
from numba import njit, prange

from .kernels import plane_point
from .layout import FAST as _FAST
from .layout import Z_MIN as _Z_MIN

STILL_LEVELS = 6
"""Largest channel change (0..255) of a camera pixel that still counts as the same picture (JPEG and sensor noise)."""
NEAREST_CAMERAS = 3
"""How many of the cameras nearest to the view by angle must be unchanged at a point (kojima blends 2, ulr 3)."""

_serials = itertools.count(1)


@njit(cache=True, parallel=True)
def _track(imgs, sizes, ref, changed_at, frame_set, still_levels):  # pragma: no cover - compiled
    """Per camera pixel inside each image (imgs, ref (N, Hm, Wm, 3) uint8; sizes (N, 2) int64 (W, H)): where a
    channel of imgs differs from ref by more than still_levels, ref takes imgs' value and changed_at (N, Hm, Wm)
    int32 the number frame_set."""
    N = imgs.shape[0]
    for i in range(N):
        W = sizes[i, 0]
        H = sizes[i, 1]
        for v in prange(H):
            for u in range(W):
                moved = False
                for c in range(3):
                    if abs(np.int64(imgs[i, v, u, c]) - np.int64(ref[i, v, u, c])) > still_levels:
                        moved = True
                if moved:
                    for c in range(3):
                        ref[i, v, u, c] = imgs[i, v, u, c]
                    changed_at[i, v, u] = frame_set


@njit(cache=True, parallel=True, fastmath=_FAST, error_model="numpy")
def _still(Q, B, G, vcenter, centers, s_pix, sizes, changed_at, since, nearest, out):  # pragma: no cover - compiled
    """out (h, w) bool: s_pix (h, w) float64 > 0 (1/m) and, for the ``nearest`` cameras by angle at the pixel's point
    (of those that see it in front of them and inside their image: the ones its colour comes from), changed_at
    (N, Hm, Wm) int32 <= since at the four pixels its colour is sampled from. G (3, 3): the virtual ray matrix,
    vcenter (3,) and centers (N, 3): the virtual and the cameras' centres (as for the colour kernel)."""
    N = Q.shape[0]
    h, w = s_pix.shape
    for y in prange(h):
        cosv = np.empty(N)
        latest = np.empty(N, np.int64)
        for x in range(w):
            s = s_pix[y, x]
            if not s > 0:
                out[y, x] = False
                continue
            z = 1.0 / s
            rx = z * (G[0, 0] * x + G[0, 1] * y + G[0, 2])
            ry = z * (G[1, 0] * x + G[1, 1] * y + G[1, 2])
            rz = z * (G[2, 0] * x + G[2, 1] * y + G[2, 2])
            m = 0
            for i in range(N):
                W = sizes[i, 0]
                H = sizes[i, 1]
                hz, u, v = plane_point(Q, B, i, x, y, s)
                if hz <= _Z_MIN or not (0.0 <= u <= W - 1 and 0.0 <= v <= H - 1):
                    continue
                dx = vcenter[0] + rx - centers[i, 0]
                dy = vcenter[1] + ry - centers[i, 1]
                dz = vcenter[2] + rz - centers[i, 2]
                cosv[m] = (dx * rx + dy * ry + dz * rz) / np.sqrt(dx * dx + dy * dy + dz * dz)
                xa = np.int64(u)
                ya = np.int64(v)
                xb = min(xa + 1, W - 1)
                yb = min(ya + 1, H - 1)
                latest[m] = max(max(changed_at[i, ya, xa], changed_at[i, ya, xb]),
                                max(changed_at[i, yb, xa], changed_at[i, yb, xb]))
                m += 1
            ok = m > 0
            for _ in range(min(nearest, m)):  # the largest cosines first (partial selection)
                b = 0
                for a in range(1, m):
                    if cosv[a] > cosv[b]:
                        b = a
                if latest[b] > since:
                    ok = False
                    break
                cosv[b] = -np.inf
            out[y, x] = ok


class ChangeTracker:
    """Which camera pixels changed in which frame set, for one renderer's cameras (images (N, Hm, Wm, 3) uint8 of
    sizes (N, 2) int64 (W, H)). :attr:`stamp` names the frame set held now: (this tracker's serial number, the
    set's number); a render made from it carries it, and only this tracker can tell what changed since."""

    def __init__(self, shape: tuple[int, int, int], still_levels: int = STILL_LEVELS) -> None:
        n, hm, wm = shape
        self.serial = next(_serials)
        self.frame_set = 0
        self.still_levels = int(still_levels)
        self._ref = np.zeros((n, hm, wm, 3), np.uint8)
        self._changed_at = np.zeros((n, hm, wm), np.int32)

    @property
    def stamp(self) -> tuple[int, int]:
        return self.serial, self.frame_set

    def update(self, imgs: np.ndarray, sizes: np.ndarray) -> None:
        """A new frame set is held (imgs (N, Hm, Wm, 3) uint8): note the camera pixels it changed."""
        self.frame_set += 1
        if self.frame_set == 1:  # the first set: every pixel new
            self._ref[:] = imgs
            self._changed_at[:] = 1
            return
        _track(imgs, sizes, self._ref, self._changed_at, np.int32(self.frame_set), np.int64(self.still_levels))

    def still_pixels(self, Q: np.ndarray, B: np.ndarray, G: np.ndarray, vcenter: np.ndarray, centers: np.ndarray,
                     s_pix: np.ndarray, sizes: np.ndarray, stamp: tuple[int, int]) -> np.ndarray | None:
        """(h, w) bool: the pixels of a render made from frame set ``stamp`` whose points, at its inverse depths
        s_pix (h, w) float64 (1/m, <= 0 where none), the NEAREST_CAMERAS cameras nearest to the view by angle that
        see them sample from pixels unchanged since (Q (N, 3, 3), B (N, 3), G (3, 3), vcenter (3,), centers (N, 3)
        float64 and sizes as for the colour kernel); None when ``stamp`` is not one of this tracker's sets up to now
        (another renderer's, or a later one)."""
        serial, since = stamp
        if serial != self.serial or not 0 < since <= self.frame_set:
            return None
        out = np.empty(s_pix.shape, np.bool_)
        _still(Q, B, G, vcenter, centers, np.ascontiguousarray(s_pix, np.float64), sizes, self._changed_at,
               np.int32(since), np.int64(NEAREST_CAMERAS), out)
        return out
