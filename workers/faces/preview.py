"""A small software rasteriser: Lambert-shaded meshes, input and output side by side as a PNG.

Orthographic front view (mesh y up, z towards the viewer), a z-buffer, per-vertex Lambert
shading interpolated across triangles (Gouraud). Both panels share one framing so that the
difference between input and output is the deformation, not a zoom.
"""
from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from workers.common.images import encode_png
from workers.faces.mesh import vertex_normals

LIGHT = np.array([-0.35, 0.45, 1.0]) / np.linalg.norm([-0.35, 0.45, 1.0])
SURFACE_BGR = np.array([150.0, 180.0, 215.0])
BACKGROUND_BGR = (40, 40, 40)


@njit(cache=True)
def _rasterise(px: np.ndarray, depth: np.ndarray, shade: np.ndarray, tris: np.ndarray, h: int, w: int):
    """Z-buffered Gouraud fill: (h, w) shade image and (h, w) bool coverage."""
    zbuf = np.full((h, w), -np.inf)
    out = np.zeros((h, w))
    for t in range(tris.shape[0]):
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        x0, y0, x1, y1, x2, y2 = px[a, 0], px[a, 1], px[b, 0], px[b, 1], px[c, 0], px[c, 1]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if abs(area) < 1e-12:
            continue
        xmin = max(int(np.ceil(min(x0, x1, x2))), 0)
        xmax = min(int(np.floor(max(x0, x1, x2))), w - 1)
        ymin = max(int(np.ceil(min(y0, y1, y2))), 0)
        ymax = min(int(np.floor(max(y0, y1, y2))), h - 1)
        for y in range(ymin, ymax + 1):
            for x in range(xmin, xmax + 1):
                l0 = ((x1 - x) * (y2 - y) - (x2 - x) * (y1 - y)) / area
                l1 = ((x2 - x) * (y0 - y) - (x0 - x) * (y2 - y)) / area
                l2 = 1.0 - l0 - l1
                if l0 < 0 or l1 < 0 or l2 < 0:
                    continue
                z = l0 * depth[a] + l1 * depth[b] + l2 * depth[c]
                if z > zbuf[y, x]:
                    zbuf[y, x] = z
                    out[y, x] = l0 * shade[a] + l1 * shade[b] + l2 * shade[c]
    return out, zbuf > -np.inf


def frame(vertex_sets: list[np.ndarray], size: int, margin: float = 0.06) -> tuple[np.ndarray, float]:
    """Shared framing of (N, 3) vertex arrays in a ``size`` x ``size`` image: (centre (2,) xy, pixels per unit)."""
    xy = np.concatenate([np.asarray(v, dtype=np.float64)[:, :2] for v in vertex_sets])
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    extent = max(float((hi - lo).max()), 1e-9)
    return (lo + hi) / 2.0, size * (1.0 - 2.0 * margin) / extent


def render(vertices: np.ndarray, triangles: np.ndarray, size: int = 320,
           view: tuple[np.ndarray, float] | None = None) -> np.ndarray:
    """uint8 (size, size, 3) BGR image of (N, 3) ``vertices`` and (T, 3) ``triangles``, front view.

    ``view``: ``(centre, pixels_per_unit)`` from :func:`frame` (default: fit this mesh).
    """
    v = np.asarray(vertices, dtype=np.float64)
    tris = np.asarray(triangles, dtype=np.int64)
    centre, scale = view if view is not None else frame([v], size)
    px = np.empty((len(v), 2))
    px[:, 0] = (v[:, 0] - centre[0]) * scale + (size - 1) / 2.0
    px[:, 1] = (size - 1) / 2.0 - (v[:, 1] - centre[1]) * scale  # image y points down
    normals = vertex_normals(v, tris)
    shade = 0.15 + 0.85 * np.abs(normals @ LIGHT)  # two-sided: open meshes show their backs too
    img, mask = _rasterise(px, v[:, 2].copy(), shade, tris, size, size)
    out = np.empty((size, size, 3), dtype=np.uint8)
    out[:] = BACKGROUND_BGR
    out[mask] = np.clip(img[mask, None] * SURFACE_BGR, 0, 255).astype(np.uint8)
    return out


def side_by_side(before: np.ndarray, after: np.ndarray, triangles: np.ndarray, labels: tuple[str, str],
                 size: int = 320) -> np.ndarray:
    """uint8 (size, 2 * size + 4, 3) BGR: (N, 3) ``before`` and ``after`` rendered with one framing, labelled."""
    view = frame([before, after], size)
    panels = [render(before, triangles, size, view), render(after, triangles, size, view)]
    for panel, label in zip(panels, labels):
        cv2.putText(panel, label, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    gap = np.full((size, 4, 3), 255, dtype=np.uint8)
    return np.concatenate([panels[0], gap, panels[1]], axis=1)


def preview_png(before: np.ndarray, after: np.ndarray, triangles: np.ndarray,
                labels: tuple[str, str] = ("input", "output"), size: int = 320) -> bytes:
    """PNG bytes of :func:`side_by_side`."""
    return encode_png(side_by_side(before, after, triangles, labels, size), level=None)
