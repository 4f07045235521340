"""The orthophoto: the surface model (:mod:`workers.drone.surface`) seen from straight above, each
ground cell coloured from the frame that sees it best, blended across the seams between frames.

1. **Visibility.** The DSM is drawn into every frame as a mesh (two triangles per 2 x 2 cell
   centres, perspective-correct depth, a z-buffer at the frame's resolution); a ground cell is seen
   by a frame when it projects inside the image and is not behind the drawn surface (a relative depth
   tolerance). A cell that every frame's drawing hides (a noisy surface can hide itself) takes the best
   frame it projects into all the same.
2. **Best frame.** Among the frames that see a cell, the one with the highest score: the ray's angle
   from the vertical (cos^4: the most nadir view shows least of the walls and least relief
   displacement), times the frame's sharpness relative to the median frame (square root; the
   Laplacian's variance), times a fall-off over the outer 5 % of the image (lens edges).
3. **Seams.** Each frame's colours are resampled into the grid (bicubic, from the image as the lens saw
   it: one interpolation, not two after an undistortion) where it sees the ground;
   OpenCV's multi-band blender joins the regions each frame won: low frequencies blend over a wide
   band (exposure differences fade), fine detail over a narrow one (no ghosting). Where a frame
   does not see a cell near its seam, its contribution there is the winning frame's colour.

Frames are :class:`~workers.drone.dense.views.View` objects (pinhole cameras, poses in the DSM's
frame; images as the lens saw them when ``dist`` gives its OpenCV distortion, else undistorted): a cell is in a
frame where the lens puts it inside the image, so the whole image counts, its corners beyond the undistorted
rectangle included. Output: RGBA uint8, alpha 0 where the DSM has no height or no frame sees it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import cv2
import numpy as np
from numba import njit

from workers.camera import Camera

from .dense.views import View
from .frames import sharpness
from .surface import Grid

_DEPTH_TOLERANCE = 0.01  # a cell farther than the drawn surface by more than this share of its depth is hidden
_EDGE_SHARE = 0.05       # the outer share of the image where a frame's score falls off to zero
_BANDS = 5               # multi-band blending levels: seams about 2^5 cells wide for the coarsest band
_BLEND_SCALE = 16
"""Colours enter OpenCV's multi-band blender multiplied by this (its pyramids are int16 and round at every
level): fed 0-255, a frame blended with itself came out 1.3 grey levels darker on average, up to 9 off, and the
synthetic survey's orthophoto 2.7 levels darker than the truth (29.3 dB; the unblended mosaic 30.0 dB); fed x16,
0.08 levels and at most 0.8 off. 255 x 16 and the Laplacian levels of it stay inside int16."""
BLEND_REACH = 2 ** (_BANDS + 2)
"""Cells around what a frame won that it still feeds the blender (its coarsest band reaches about 2^5 cells)."""


@dataclass
class Orthophoto:
    """``rgba`` (H, W, 4) uint8 RGBA on the grid; ``source`` (H, W) int16 the index of the frame each
    cell's colour came from (-1: none); ``coverage`` the share of DSM cells that got a colour."""

    rgba: np.ndarray
    source: np.ndarray
    coverage: float
    seconds: dict[str, float]


@njit(cache=True)
def _raster_depth(xs, ys, dsm, K, R, t, w, h):  # pragma: no cover - compiled
    """Depth (h, w) float32 of the DSM mesh seen by one camera (inf where it shows none)."""
    zbuf = np.full((h, w), np.inf, np.float32)
    H, W = dsm.shape
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    U = np.empty((H, W))
    V = np.empty((H, W))
    Z = np.empty((H, W))
    for r in range(H):
        for c in range(W):
            z = dsm[r, c]
            if not np.isfinite(z):
                Z[r, c] = -1.0
                continue
            x, y = xs[c], ys[r]
            p0 = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]
            p1 = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]
            p2 = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
            Z[r, c] = p2
            if p2 > 1e-9:
                U[r, c] = fx * p0 / p2 + cx
                V[r, c] = fy * p1 / p2 + cy
    tri = np.empty((3, 3))
    for r in range(H - 1):
        for c in range(W - 1):
            for k in range(2):
                if k == 0:
                    a, b, d = (r, c), (r, c + 1), (r + 1, c)
                else:
                    a, b, d = (r + 1, c + 1), (r + 1, c), (r, c + 1)
                ok = True
                for j, (rr, cc) in enumerate((a, b, d)):
                    if Z[rr, cc] <= 1e-9:
                        ok = False
                        break
                    tri[j, 0] = U[rr, cc]
                    tri[j, 1] = V[rr, cc]
                    tri[j, 2] = 1.0 / Z[rr, cc]
                if not ok:
                    continue
                u0 = max(int(math.ceil(min(tri[0, 0], tri[1, 0], tri[2, 0]))), 0)
                u1 = min(int(math.floor(max(tri[0, 0], tri[1, 0], tri[2, 0]))), w - 1)
                v0 = max(int(math.ceil(min(tri[0, 1], tri[1, 1], tri[2, 1]))), 0)
                v1 = min(int(math.floor(max(tri[0, 1], tri[1, 1], tri[2, 1]))), h - 1)
                if u0 > u1 or v0 > v1:
                    continue
                den = (tri[1, 1] - tri[2, 1]) * (tri[0, 0] - tri[2, 0]) + (tri[2, 0] - tri[1, 0]) * (tri[0, 1] - tri[2, 1])
                if abs(den) < 1e-12:
                    continue
                for v in range(v0, v1 + 1):
                    for u in range(u0, u1 + 1):
                        l0 = ((tri[1, 1] - tri[2, 1]) * (u - tri[2, 0]) + (tri[2, 0] - tri[1, 0]) * (v - tri[2, 1])) / den
                        l1 = ((tri[2, 1] - tri[0, 1]) * (u - tri[2, 0]) + (tri[0, 0] - tri[2, 0]) * (v - tri[2, 1])) / den
                        l2 = 1.0 - l0 - l1
                        if l0 < -1e-9 or l1 < -1e-9 or l2 < -1e-9:
                            continue
                        inv = l0 * tri[0, 2] + l1 * tri[1, 2] + l2 * tri[2, 2]
                        if inv > 0:
                            depth = 1.0 / inv
                            if depth < zbuf[v, u]:
                                zbuf[v, u] = depth
    return zbuf


@njit(cache=True)
def _lens_pixel(u, v, fx, fy, cx, cy, d):  # pragma: no cover - compiled
    """An undistorted pixel (u, v) -> where a lens with OpenCV distortion d (5,) (k1 k2 p1 p2 k3) shows it."""
    xn = (u - cx) / fx
    yn = (v - cy) / fy
    xy = xn * yn
    r2 = xn * xn + yn * yn
    radial = 1.0 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]))
    xd = xn * radial + 2.0 * d[2] * xy + d[3] * (r2 + 2.0 * xn * xn)
    yd = yn * radial + d[2] * (r2 + 2.0 * yn * yn) + 2.0 * d[3] * xy
    return fx * xd + cx, fy * yd + cy


@njit(cache=True)
def _score_view(xs, ys, dsm, K, R, t, C, w, h, dist, zbuf, ox, oy, weight, view, best, label, best_hidden,
                label_hidden, mapu, mapv, vis, r0, c0):  # pragma: no cover
    """Score the DSM cells that one frame shows, in the window of the grid (mapu's shape) starting at row r0,
    column c0 (see the module docstring): a cell is shown where the lens (OpenCV distortion ``dist`` (5,)) puts it
    inside the w x h image. Where the frame sees the cell (not behind the surface drawn in ``zbuf``, whose pixel
    (0, 0) is the undistorted pixel (ox, oy)), update best (H, W) and label (H, W) where it wins; where the drawn
    surface hides it, best_hidden and label_hidden (the fallback for cells no frame sees: a noisy surface can hide
    itself). Write the image position of each shown cell into mapu/mapv (-1 elsewhere) and vis = 1 where it sees
    it."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    margin = _EDGE_SHARE * max(w, h)
    mh, mw = mapu.shape
    zh, zw = zbuf.shape
    for r in range(r0, r0 + mh):
        for c in range(c0, c0 + mw):
            z = dsm[r, c]
            if not np.isfinite(z):
                continue
            x, y = xs[c], ys[r]
            p0 = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]
            p1 = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]
            p2 = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
            if p2 <= 1e-9:
                continue
            un = fx * p0 / p2 + cx
            vn = fy * p1 / p2 + cy
            u, v = _lens_pixel(un, vn, fx, fy, cx, cy, dist)
            if u < 0 or v < 0 or u > w - 1 or v > h - 1:
                continue
            mapu[r - r0, c - c0] = u
            mapv[r - r0, c - c0] = v
            dx, dy, dz = C[0] - x, C[1] - y, C[2] - z
            cos = dz / math.sqrt(dx * dx + dy * dy + dz * dz)
            if cos <= 0:
                continue
            edge = min(min(u, w - 1 - u), min(v, h - 1 - v)) / margin
            s = cos ** 4 * min(edge, 1.0) * weight
            zi = int(vn - oy + 0.5)
            zj = int(un - ox + 0.5)
            front = zbuf[zi, zj] if 0 <= zi < zh and 0 <= zj < zw else np.inf
            if p2 <= front * (1.0 + _DEPTH_TOLERANCE):
                vis[r - r0, c - c0] = 1
                if s > best[r, c]:
                    best[r, c] = s
                    label[r, c] = view
            elif s > best_hidden[r, c]:
                best_hidden[r, c] = s
                label_hidden[r, c] = view


@njit(cache=True)
def _footprint(xs, ys, dsm, K, R, t, w, h, dist):  # pragma: no cover - compiled
    """Rows and columns (r0, r1, c0, c1), inclusive, of the cells the lens (distortion ``dist`` (5,)) shows inside
    the w x h image; r0 = -1 if none."""
    H, W = dsm.shape
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    r0, r1, c0, c1 = H, -1, W, -1
    for r in range(H):
        for c in range(W):
            z = dsm[r, c]
            if not np.isfinite(z):
                continue
            x, y = xs[c], ys[r]
            p2 = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
            if p2 <= 1e-9:
                continue
            un = fx * (R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]) / p2 + cx
            vn = fy * (R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]) / p2 + cy
            u, v = _lens_pixel(un, vn, fx, fy, cx, cy, dist)
            if 0 <= u <= w - 1 and 0 <= v <= h - 1:
                r0, r1, c0, c1 = min(r0, r), max(r1, r), min(c0, c), max(c1, c)
    if r1 < 0:
        return -1, -1, -1, -1
    return r0, r1, c0, c1


def _undistorted_extent(K: np.ndarray, dist: np.ndarray, w: int, h: int) -> tuple[int, int, int, int]:
    """(ox, oy, width, height): the undistorted pixels the lens's w x h image reaches, as a canvas whose pixel
    (0, 0) is the undistorted pixel (ox, oy) (the frame's z-buffer is drawn there)."""
    if not np.any(dist):
        return 0, 0, w, h
    s = np.linspace(0.0, 1.0, 33)
    border = np.concatenate([np.column_stack([s * (w - 1), np.zeros_like(s)]),
                             np.column_stack([s * (w - 1), np.full_like(s, h - 1)]),
                             np.column_stack([np.zeros_like(s), s * (h - 1)]),
                             np.column_stack([np.full_like(s, w - 1), s * (h - 1)])])
    und = cv2.undistortPointsIter(border.reshape(-1, 1, 2), K, dist, None, K,
                                  (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-6)).reshape(-1, 2)
    ox, oy = int(math.floor(min(und[:, 0].min(), 0.0))), int(math.floor(min(und[:, 1].min(), 0.0)))
    x1, y1 = int(math.ceil(max(und[:, 0].max(), w - 1))), int(math.ceil(max(und[:, 1].max(), h - 1)))
    return ox, oy, x1 - ox + 1, y1 - oy + 1


def _five(dist: np.ndarray | None) -> np.ndarray:
    """OpenCV distortion as the kernels take it: k1 k2 p1 p2 k3 (5,) float64 (zeros: none)."""
    d = np.zeros(5)
    if dist is not None:
        dist = np.asarray(dist, np.float64).ravel()
        if len(dist) > 5 and np.any(dist[5:]):
            raise ValueError("the orthophoto samples through a lens of at most five distortion coefficients "
                             "(k1 k2 p1 p2 k3); undistort the frames first")
        d[:min(5, len(dist))] = dist[:5]
    return d


def orthophoto(dsm: np.ndarray, grid: Grid, views: Sequence[View],
               progress: Callable[[float, str], None] | None = None, dist: np.ndarray | None = None) -> Orthophoto:
    """Render the orthophoto of ``dsm`` (H, W) float32 heights (NaN: nodata) on ``grid`` from ``views``
    (their images (h, w, 3) uint8 BGR; K, R, t in the grid's world frame), the images seen through a lens
    with OpenCV distortion ``dist`` (n,) (None: undistorted images). See the module docstring.
    ``progress(fraction, stage)`` reports 'orthophoto k/N' per frame and 'orthophoto blend'."""
    sharp = np.array([sharpness(cv2.cvtColor(v.image, cv2.COLOR_BGR2GRAY)) for v in views])
    weights = np.sqrt(sharp / max(float(np.median(sharp)), 1e-9)) if len(sharp) else sharp
    return orthophoto_of([v.camera for v in views], weights, lambda i: views[i].image, dsm, grid, progress, dist)


def orthophoto_of(cameras: Sequence[Camera], weights: np.ndarray, image: Callable[[int], np.ndarray],
                  dsm: np.ndarray, grid: Grid, progress: Callable[[float, str], None] | None = None,
                  dist: np.ndarray | None = None) -> Orthophoto:
    """:func:`orthophoto` from the frames' ``cameras`` and sharpness ``weights`` (n,) (each frame's score factor,
    the square root of its Laplacian variance over the median frame's), reading a frame's image only to blend the
    cells it won (``image(i)`` -> (h, w, 3) uint8 BGR at its camera's size, one at a time: a ground tile of a
    survey holds one image at a time, whatever their number)."""
    import time

    t0 = time.perf_counter()
    H, W = dsm.shape
    xs, ys = grid.centres()
    dsm64 = np.ascontiguousarray(dsm, np.float64)
    best = np.zeros((H, W))
    label = np.full((H, W), -1, np.int16)
    best_hidden = np.zeros((H, W))
    label_hidden = np.full((H, W), -1, np.int16)
    windows = []
    lens = _five(dist)
    for i, cam in enumerate(cameras):
        if progress is not None:
            progress(0.8 * i / max(len(cameras), 1), f"orthophoto {i + 1}/{len(cameras)}")
        w, h = cam.size
        K, R, tv = cam.K, cam.R, cam.t
        r0, r1, c0, c1 = _footprint(xs, ys, dsm64, K, R, tv, w, h, lens)
        if r0 < 0:
            windows.append(None)
            continue
        ox, oy, zw, zh = _undistorted_extent(K, lens, w, h)
        Kz = K.copy()
        Kz[0, 2] -= ox
        Kz[1, 2] -= oy
        zbuf = _raster_depth(xs[c0:c1 + 1], ys[r0:r1 + 1], dsm64[r0:r1 + 1, c0:c1 + 1], Kz, R, tv, zw, zh)
        mapu = np.full((r1 - r0 + 1, c1 - c0 + 1), -1.0, np.float32)
        mapv = np.full_like(mapu, -1.0)
        vis = np.zeros(mapu.shape, np.uint8)
        _score_view(xs, ys, dsm64, K, R, tv, cam.center, w, h, lens, zbuf, float(ox), float(oy), float(weights[i]), i,
                    best, label, best_hidden, label_hidden, mapu, mapv, vis, r0, c0)
        windows.append((r0, c0, mapu, mapv, vis.astype(bool)))
    label = np.where(label >= 0, label, label_hidden)
    t1 = time.perf_counter()
    if progress is not None:
        progress(0.8, "orthophoto blend")
    rgba = _blend(image, windows, label, H, W)
    covered = np.isfinite(dsm)
    coverage = float((label[covered] >= 0).mean()) if covered.any() else 0.0
    return Orthophoto(rgba, label, coverage, {"visibility_and_scores": round(t1 - t0, 3),
                                              "blend": round(time.perf_counter() - t1, 3)})


def _blend(image: Callable[[int], np.ndarray], windows: list, label: np.ndarray, H: int, W: int) -> np.ndarray:
    """Multi-band blend of each frame's colours over the cells it won (module docstring, step 3); a frame's image
    is read once, and only the part of its window within :data:`BLEND_REACH` cells of what it won is kept."""
    crops = []
    hard = np.zeros((H, W, 3), np.uint8)
    for i, win in enumerate(windows):
        if win is None:
            continue
        r0, c0, mapu, mapv, seen = win
        mine = label[r0:r0 + mapu.shape[0], c0:c0 + mapu.shape[1]] == i
        if not mine.any():
            continue
        rows, cols = np.flatnonzero(mine.any(axis=1)), np.flatnonzero(mine.any(axis=0))
        a0, a1 = max(0, rows[0] - BLEND_REACH), min(mine.shape[0], rows[-1] + 1 + BLEND_REACH)
        b0, b1 = max(0, cols[0] - BLEND_REACH), min(mine.shape[1], cols[-1] + 1 + BLEND_REACH)
        colours = cv2.remap(image(i), mapu[a0:a1, b0:b1], mapv[a0:a1, b0:b1], cv2.INTER_CUBIC,
                            borderMode=cv2.BORDER_REPLICATE)
        mine, seen = mine[a0:a1, b0:b1], seen[a0:a1, b0:b1]
        hard_win = hard[r0 + a0:r0 + a1, c0 + b0:c0 + b1]
        hard_win[mine] = colours[mine]
        crops.append((r0 + a0, c0 + b0, colours, seen, mine))
    rgba = np.zeros((H, W, 4), np.uint8)
    if not crops:
        return rgba
    blender = cv2.detail_MultiBandBlender(0, _BANDS)
    blender.prepare((0, 0, W, H))
    for r0, c0, colours, seen, mine in crops:
        h, w = colours.shape[:2]
        img = np.where(seen[..., None], colours, hard[r0:r0 + h, c0:c0 + w])
        blender.feed(img.astype(np.int16) * _BLEND_SCALE, mine.astype(np.uint8) * 255, (int(c0), int(r0)))
    out, _ = blender.blend(None, None)
    bgr = np.clip(np.rint(out / _BLEND_SCALE), 0, 255).astype(np.uint8)
    rgba[..., :3] = bgr[..., ::-1]
    rgba[..., 3] = np.where(label >= 0, 255, 0).astype(np.uint8)
    rgba[label < 0, :3] = 0
    return rgba
