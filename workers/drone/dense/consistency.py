"""Geometric consistency of depth maps across views and the normals of a depth map: the plain-numpy
definitions the compiled fusion (:mod:`workers.drone.dense.fusion`) reproduces."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .views import View


@dataclass
class Agreement:
    """Which neighbours agree with a reference's depths: ``count`` (h, w) int16 frames that agree,
    the reference included (0 where it has no depth); per neighbour its name and, for every reference
    pixel with a depth (``ys``, ``xs``), whether it agrees (``agree`` (M,) bool), where it landed there
    (``u``, ``v`` (M,) int32) and that neighbour's point (``X`` (M, 3) float64)."""

    count: np.ndarray
    ys: np.ndarray
    xs: np.ndarray
    names: list[str] = field(default_factory=list)
    agree: list[np.ndarray] = field(default_factory=list)
    u: list[np.ndarray] = field(default_factory=list)
    v: list[np.ndarray] = field(default_factory=list)
    X: list[np.ndarray] = field(default_factory=list)


def consistency(ref: View, ref_depth: np.ndarray, others: Sequence[View], other_depths: Sequence[np.ndarray],
                max_reprojection_px: float = 1.0, max_depth_ratio: float = 0.01) -> Agreement:
    """Geometric consistency of ``ref_depth`` (h, w) float32 (0 = none) with each other view's depth map
    (same size as that view's image): the point of a reference pixel is projected into the other view,
    that view's depth at the nearest pixel is back-projected and projected into the reference; it agrees
    when that lands within ``max_reprojection_px`` of the pixel and the two depths in the other view differ
    by at most ``max_depth_ratio`` of its depth."""
    ys, xs = np.nonzero(ref_depth > 0)
    d = ref_depth[ys, xs]
    X = ref.camera.backproject(np.column_stack([xs, ys]), d)
    count = np.zeros(ref_depth.shape, np.int16)
    count[ys, xs] = 1
    out = Agreement(count, ys.astype(np.int32), xs.astype(np.int32))
    for view, dm in zip(others, other_depths):
        uv, z = view.camera.project(X)
        hn, wn = dm.shape
        u = np.rint(np.nan_to_num(uv[:, 0], nan=-1.0)).astype(np.int64)
        v = np.rint(np.nan_to_num(uv[:, 1], nan=-1.0)).astype(np.int64)
        inside = (z > 0) & (u >= 0) & (v >= 0) & (u < wn) & (v < hn)
        dn = np.zeros(len(d), np.float64)
        dn[inside] = dm[v[inside], u[inside]]
        has = inside & (dn > 0)
        Xn = np.zeros_like(X)
        Xn[has] = view.camera.backproject(np.column_stack([u[has], v[has]]), dn[has])
        back, _ = ref.camera.project(Xn[has])
        err = np.full(len(d), np.inf)
        err[has] = np.hypot(back[:, 0] - xs[has], back[:, 1] - ys[has])
        ratio = np.full(len(d), np.inf)
        ratio[has] = np.abs(z[has] - dn[has]) / dn[has]
        ok = has & (err <= max_reprojection_px) & (ratio <= max_depth_ratio)
        count[ys[ok], xs[ok]] += 1
        out.names.append(view.camera.name)
        out.agree.append(ok)
        out.u.append(u.astype(np.int32))
        out.v.append(v.astype(np.int32))
        out.X.append(Xn)
    return out


def camera_normals(view: View, depth: np.ndarray, max_jump: float = 0.05) -> np.ndarray:
    """Unit normals (h, w, 3) float32 in world coordinates of a depth map (h, w) float32 (0 = none): the
    cross product of the camera-space points' central differences along x and y (one-sided at a hole or
    where the depth jumps by more than ``max_jump`` of itself), turned towards the camera; where neither
    difference exists, the direction back to the camera."""
    h, w = depth.shape
    Kinv = np.linalg.inv(view.camera.K)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([xs, ys, np.ones_like(xs)], -1) @ Kinv.T
    P = rays * depth[:, :, None].astype(np.float64)
    valid = depth > 0

    def diff(axis: int) -> np.ndarray:
        fwd = np.zeros_like(P)
        bwd = np.zeros_like(P)
        okf = np.zeros((h, w), bool)
        okb = np.zeros((h, w), bool)
        sl_a = [slice(None)] * 2
        sl_b = [slice(None)] * 2
        sl_a[axis] = slice(0, -1)
        sl_b[axis] = slice(1, None)
        a, b = tuple(sl_a), tuple(sl_b)
        near_ = valid[a] & valid[b] & (np.abs(depth[b] - depth[a]) <= max_jump * np.maximum(depth[a], 1e-12))
        fwd[a] = np.where(near_[..., None], P[b] - P[a], 0.0)
        okf[a] = near_
        bwd[b] = np.where(near_[..., None], P[b] - P[a], 0.0)
        okb[b] = near_
        both = okf & okb
        d = np.where(both[..., None], 0.5 * (fwd + bwd), fwd + bwd)
        return d, okf | okb

    dx, okx = diff(1)
    dy, oky = diff(0)
    n = np.cross(dx, dy)
    norm = np.linalg.norm(n, axis=-1)
    good = okx & oky & (norm > 0)
    toward = -rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    n = np.where(good[..., None], n / np.where(norm > 0, norm, 1.0)[..., None], toward)
    flip = np.sum(n * rays, axis=-1) > 0
    n[flip] *= -1
    return (n @ view.camera.R).astype(np.float32)

