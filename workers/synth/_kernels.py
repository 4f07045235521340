"""Compiled ray-primitive intersections that update a z-buffer in place (numba).

All take the ray origin ``o`` (3,), directions ``D`` (N, 3) and the buffers ``best_t`` (N,),
``ids`` (N,) int64 and ``normals`` (N, 3); a hit nearer than ``best_t`` overwrites all three with
the hit distance, the primitive index ``k`` and the world normal.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

_EPS = 1e-9


@njit(cache=True, parallel=True)
def sphere_hits(o, D, c, r, k, best_t, ids, normals):  # pragma: no cover - compiled
    ocx, ocy, ocz = o[0] - c[0], o[1] - c[1], o[2] - c[2]
    cc = ocx * ocx + ocy * ocy + ocz * ocz - r * r
    for i in prange(D.shape[0]):
        dx, dy, dz = D[i, 0], D[i, 1], D[i, 2]
        a = dx * dx + dy * dy + dz * dz
        b = dx * ocx + dy * ocy + dz * ocz
        disc = b * b - a * cc
        if disc < 0:
            continue
        sq = np.sqrt(disc)
        t = (-b - sq) / a
        if t <= _EPS:
            t = (-b + sq) / a
        if t <= _EPS or t >= best_t[i]:
            continue
        best_t[i] = t
        ids[i] = k
        normals[i, 0] = (ocx + t * dx) / r
        normals[i, 1] = (ocy + t * dy) / r
        normals[i, 2] = (ocz + t * dz) / r


@njit(cache=True, parallel=True)
def box_hits(o, D, Rb, c, h, k, best_t, ids, normals):  # pragma: no cover - compiled
    ol = Rb @ (o - c)
    for i in prange(D.shape[0]):
        tmin = -np.inf
        tmax = np.inf
        face_in = 0
        face_out = 0
        sign_in = 0.0
        sign_out = 0.0
        miss = False
        for ax in range(3):
            d = Rb[ax, 0] * D[i, 0] + Rb[ax, 1] * D[i, 1] + Rb[ax, 2] * D[i, 2]
            if abs(d) < 1e-15:
                if ol[ax] < -h[ax] or ol[ax] > h[ax]:
                    miss = True
                    break
                continue
            t1 = (-h[ax] - ol[ax]) / d
            t2 = (h[ax] - ol[ax]) / d
            s = -1.0 if d > 0 else 1.0  # outward normal of the face entered first
            if t1 > t2:
                t1, t2 = t2, t1
            if t1 > tmin:
                tmin, face_in, sign_in = t1, ax, s
            if t2 < tmax:
                tmax, face_out, sign_out = t2, ax, -s
        if miss or tmax < tmin or tmax <= _EPS:
            continue
        if tmin > _EPS:
            t, face, sgn = tmin, face_in, sign_in
        else:
            t, face, sgn = tmax, face_out, sign_out
        if t >= best_t[i]:
            continue
        best_t[i] = t
        ids[i] = k
        for j in range(3):
            normals[i, j] = sgn * Rb[face, j]  # box axis `face` in world is row `face` of Rb


@njit(cache=True, parallel=True)
def plane_hits(o, D, p, n, k, best_t, ids, normals):  # pragma: no cover - compiled
    num = (p[0] - o[0]) * n[0] + (p[1] - o[1]) * n[1] + (p[2] - o[2]) * n[2]
    for i in prange(D.shape[0]):
        den = D[i, 0] * n[0] + D[i, 1] * n[1] + D[i, 2] * n[2]
        if den == 0.0:
            continue
        t = num / den
        if t <= _EPS or t >= best_t[i]:
            continue
        best_t[i] = t
        ids[i] = k
        normals[i, 0] = n[0]
        normals[i, 1] = n[1]
        normals[i, 2] = n[2]


# --- shadow rays: one direction, an origin per ray -------------------------------------------------
@njit(cache=True, parallel=True)
def sphere_blocks(O, d, c, r, blocked):  # pragma: no cover - compiled
    """blocked[i] = 1 where the ray O[i] + t d (t > 0) meets the sphere (c, r); O (N, 3), d (3,) unit."""
    for i in prange(O.shape[0]):
        if blocked[i]:
            continue
        ox, oy, oz = O[i, 0] - c[0], O[i, 1] - c[1], O[i, 2] - c[2]
        b = ox * d[0] + oy * d[1] + oz * d[2]
        cc = ox * ox + oy * oy + oz * oz - r * r
        disc = b * b - cc
        if disc < 0:
            continue
        sq = np.sqrt(disc)
        if -b + sq > _EPS:  # the far hit is ahead: the sphere is on the ray (or the origin is inside it)
            blocked[i] = 1


@njit(cache=True, parallel=True)
def box_blocks(O, d, Rb, c, h, blocked):  # pragma: no cover - compiled
    """blocked[i] = 1 where the ray O[i] + t d (t > 0) meets the oriented box (Rb world-to-box, centre c,
    half sizes h), slab method as :func:`box_hits`."""
    dl = Rb @ d
    for i in prange(O.shape[0]):
        if blocked[i]:
            continue
        tmin = -np.inf
        tmax = np.inf
        miss = False
        for ax in range(3):
            o = Rb[ax, 0] * (O[i, 0] - c[0]) + Rb[ax, 1] * (O[i, 1] - c[1]) + Rb[ax, 2] * (O[i, 2] - c[2])
            if abs(dl[ax]) < 1e-15:
                if o < -h[ax] or o > h[ax]:
                    miss = True
                    break
                continue
            t1 = (-h[ax] - o) / dl[ax]
            t2 = (h[ax] - o) / dl[ax]
            if t1 > t2:
                t1, t2 = t2, t1
            tmin = max(tmin, t1)
            tmax = min(tmax, t2)
        if not miss and tmax >= tmin and tmax > _EPS:
            blocked[i] = 1
