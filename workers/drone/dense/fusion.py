"""Fusion of the depth maps into one coloured point cloud with normals: per reference pixel, the frames
whose depth maps agree on it (the tests of :func:`.consistency.consistency`), the mean
of their points and colours and the reference's normal, in one compiled pass per reference."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from numba import njit, prange

from .views import View


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
    neighbour pixels that agreed with a pixel kept (count >= min_views). Same tests as
    :func:`.consistency.consistency`."""
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
         progress: Callable[[int], None] | None = None, max_jump: float = 0.05,
         references: Sequence[int] | None = None, masks: Sequence[np.ndarray | None] | None = None) -> DenseCloud:
    """Fuse the depth maps (one per view, each (h, w) float32 at its view's size, 0 = none) into one cloud.

    neighbours[i]: indices of the views checked against view i (the tests of :func:`.consistency.consistency`; all views
    one image size). A pixel whose depth at least ``min_views`` frames agree on (the reference included)
    becomes a point: the mean of the agreeing frames' points and of their colours, the reference's normal
    (:func:`.consistency.camera_normals`, ``max_jump``). Views are taken in order (``references``: only these, in
    this order; the others serve as neighbours); the neighbour pixels that agreed are then marked used and never
    start a point of their own. ``masks[i]`` (h, w) bool: the only pixels of view i that may start a point (a
    ground tile's, :mod:`workers.drone.survey.surface`). ``progress(i)`` is called after view i.
    Compiled, one pass over the pixels per reference (:func:`_fuse_view`)."""
    used = [np.zeros(d.shape, bool) for d in depths]
    pts, cols, nrms, cnts = [], [], [], []
    for i in (range(len(views)) if references is None else references):
        view, dm = views[i], depths[i]
        blocked = used[i] if masks is None or masks[i] is None else used[i] | ~masks[i]
        free = np.where(blocked, 0.0, dm).astype(np.float32)
        nb = [j for j in neighbours[i] if j != i]
        h, w = dm.shape
        hn, wn = (depths[nb[0]].shape if nb else (1, 1))
        cam = view.camera
        ncams = [views[j].camera for j in nb]
        nK = np.stack([c.K for c in ncams]) if nb else np.zeros((0, 3, 3))
        nKinv = np.stack([np.linalg.inv(c.K) for c in ncams]) if nb else np.zeros((0, 3, 3))
        nR = np.stack([c.R for c in ncams]) if nb else np.zeros((0, 3, 3))
        nt = np.stack([c.t for c in ncams]) if nb else np.zeros((0, 3))
        ndepth = np.stack([depths[j] for j in nb]).astype(np.float32) if nb else np.zeros((0, 1, 1), np.float32)
        nimage = np.stack([views[j].image for j in nb]) if nb else np.zeros((0, 1, 1, 3), np.uint8)
        count = np.zeros((h, w), np.int16)
        X = np.zeros((h, w, 3), np.float32)
        col = np.zeros((h, w, 3), np.float32)
        nrm = np.zeros((h, w, 3), np.float32)
        nused = np.zeros((len(nb), hn, wn), np.bool_)
        _fuse_view(free, np.ascontiguousarray(dm, np.float32), np.linalg.inv(cam.K), cam.K, cam.R, cam.t,
                   np.ascontiguousarray(view.image), nK, nKinv, nR, nt,
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
