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
frame; images as the lens saw them when ``dist`` gives its OpenCV distortion, else undistorted). Output:
RGBA uint8, alpha 0 where the DSM has no height or no frame sees it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import cv2
import numpy as np
from numba import njit

from workers.camera import distort_normalised

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
def _score_view(xs, ys, dsm, K, R, t, C, w, h, zbuf, weight, view, best, label, best_hidden, label_hidden, mapu, mapv,
                vis, r0, c0):  # pragma: no cover
    """Score the DSM cells that project into one frame, in the window of the grid (mapu's shape) starting
    at row r0, column c0 (see the module docstring): where the frame sees the cell, update best (H, W) and
    label (H, W) where it wins; where the drawn surface hides it, best_hidden and label_hidden (the
    fallback for cells no frame sees: a noisy surface can hide itself). Write the frame's pixel position of
    each cell into mapu/mapv (-1 outside the image) and vis = 1 where the frame sees it."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    margin = _EDGE_SHARE * max(w, h)
    mh, mw = mapu.shape
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
            u = fx * p0 / p2 + cx
            v = fy * p1 / p2 + cy
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
            if p2 <= zbuf[int(v + 0.5), int(u + 0.5)] * (1.0 + _DEPTH_TOLERANCE):
                vis[r - r0, c - c0] = 1
                if s > best[r, c]:
                    best[r, c] = s
                    label[r, c] = view
            elif s > best_hidden[r, c]:
                best_hidden[r, c] = s
                label_hidden[r, c] = view


@njit(cache=True)
def _footprint(xs, ys, dsm, K, R, t, w, h):  # pragma: no cover - compiled
    """Rows and columns (r0, r1, c0, c1), inclusive, of the cells that project into the image; r0 = -1 if none."""
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
            u = fx * (R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]) / p2 + cx
            v = fy * (R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]) / p2 + cy
            if 0 <= u <= w - 1 and 0 <= v <= h - 1:
                r0, r1, c0, c1 = min(r0, r), max(r1, r), min(c0, c), max(c1, c)
    if r1 < 0:
        return -1, -1, -1, -1
    return r0, r1, c0, c1


def orthophoto(dsm: np.ndarray, grid: Grid, views: Sequence[View],
               progress: Callable[[float, str], None] | None = None, dist: np.ndarray | None = None) -> Orthophoto:
    """Render the orthophoto of ``dsm`` (H, W) float32 heights (NaN: nodata) on ``grid`` from ``views``
    (their images (h, w, 3) uint8 BGR; K, R, t in the grid's world frame), the images seen through a lens
    with OpenCV distortion ``dist`` (n,) (None: undistorted images). See the module docstring.
    ``progress(fraction, stage)`` reports 'orthophoto k/N' per frame and 'orthophoto blend'."""
    import time

    t0 = time.perf_counter()
    H, W = dsm.shape
    xs, ys = grid.centres()
    dsm64 = np.ascontiguousarray(dsm, np.float64)
    sharp = np.array([sharpness(cv2.cvtColor(v.image, cv2.COLOR_BGR2GRAY)) for v in views])
    weights = np.sqrt(sharp / max(float(np.median(sharp)), 1e-9))
    best = np.zeros((H, W))
    label = np.full((H, W), -1, np.int16)
    best_hidden = np.zeros((H, W))
    label_hidden = np.full((H, W), -1, np.int16)
    windows = []
    for i, v in enumerate(views):
        if progress is not None:
            progress(0.8 * i / max(len(views), 1), f"orthophoto {i + 1}/{len(views)}")
        w, h = v.camera.size
        K, R, tv = v.camera.K, v.camera.R, v.camera.t
        r0, r1, c0, c1 = _footprint(xs, ys, dsm64, K, R, tv, w, h)
        if r0 < 0:
            windows.append(None)
            continue
        zbuf = _raster_depth(xs[c0:c1 + 1], ys[r0:r1 + 1], dsm64[r0:r1 + 1, c0:c1 + 1], K, R, tv, w, h)
        mapu = np.full((r1 - r0 + 1, c1 - c0 + 1), -1.0, np.float32)
        mapv = np.full_like(mapu, -1.0)
        vis = np.zeros(mapu.shape, np.uint8)
        _score_view(xs, ys, dsm64, K, R, tv, v.camera.center, w, h, zbuf, float(weights[i]), i, best, label, best_hidden,
                    label_hidden, mapu, mapv, vis, r0, c0)
        if dist is not None:
            mapu, mapv, inside = _through_lens(mapu, mapv, K, dist, w, h)
            vis &= inside
        windows.append((r0, c0, mapu, mapv, vis.astype(bool)))
    label = np.where(label >= 0, label, label_hidden)
    t1 = time.perf_counter()
    if progress is not None:
        progress(0.8, "orthophoto blend")
    rgba = _blend(views, windows, label, H, W)
    covered = np.isfinite(dsm)
    coverage = float((label[covered] >= 0).mean()) if covered.any() else 0.0
    return Orthophoto(rgba, label, coverage, {"visibility_and_scores": round(t1 - t0, 3),
                                              "blend": round(time.perf_counter() - t1, 3)})


def _through_lens(mapu: np.ndarray, mapv: np.ndarray, K: np.ndarray, dist: np.ndarray, w: int, h: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Undistorted pixel positions (mapu, mapv, -1: none) -> where the lens shows them (float32), and
    (uint8) whether that lies inside the w x h image."""
    ok = mapu >= 0
    u = mapu.copy()
    v = mapv.copy()
    if ok.any():
        xn = (mapu[ok] - K[0, 2]) / K[0, 0]
        yn = (mapv[ok] - K[1, 2]) / K[1, 1]
        u[ok], v[ok] = distort_normalised(xn.astype(np.float64), yn.astype(np.float64), K, dist)
    inside = ok & (u >= 0) & (v >= 0) & (u <= w - 1) & (v <= h - 1)
    return u, v, inside.astype(np.uint8)


def _blend(views: Sequence[View], windows: list, label: np.ndarray, H: int, W: int) -> np.ndarray:
    """Multi-band blend of each frame's colours over the cells it won (module docstring, step 3)."""
    samples = []
    hard = np.zeros((H, W, 3), np.uint8)
    for i, (v, win) in enumerate(zip(views, windows)):
        if win is None:
            samples.append(None)
            continue
        r0, c0, mapu, mapv, seen = win
        colours = cv2.remap(v.image, mapu, mapv, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
        mine = label[r0:r0 + mapu.shape[0], c0:c0 + mapu.shape[1]] == i
        hard_win = hard[r0:r0 + mapu.shape[0], c0:c0 + mapu.shape[1]]
        hard_win[mine] = colours[mine]
        samples.append((r0, c0, colours, seen, mine))
    blender = cv2.detail_MultiBandBlender(0, _BANDS)
    blender.prepare((0, 0, W, H))
    fed = False
    for s in samples:
        if s is None or not s[4].any():
            continue
        r0, c0, colours, seen, mine = s
        h, w = colours.shape[:2]
        img = np.where(seen[..., None], colours, hard[r0:r0 + h, c0:c0 + w])
        blender.feed(img.astype(np.int16) * _BLEND_SCALE, mine.astype(np.uint8) * 255, (int(c0), int(r0)))
        fed = True
    rgba = np.zeros((H, W, 4), np.uint8)
    if not fed:
        return rgba
    out, _ = blender.blend(None, None)
    bgr = np.clip(np.rint(out / _BLEND_SCALE), 0, 255).astype(np.uint8)
    rgba[..., :3] = bgr[..., ::-1]
    rgba[..., 3] = np.where(label >= 0, 255, 0).astype(np.uint8)
    rgba[label < 0, :3] = 0
    return rgba
