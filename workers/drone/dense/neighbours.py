"""What the sparse model says about a reference frame: the points it sees, its best neighbours for the sweep
and the depth range to sweep."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from workers.camera import Camera

from .views import View


def visible_points(camera: Camera, points: np.ndarray) -> np.ndarray:
    """Indices (M,) int64 of ``points`` (P, 3) in front of ``camera`` and inside its image."""
    if len(points) == 0:
        return np.zeros(0, np.int64)
    uv, z = camera.project(points)
    w, h = camera.size
    ok = (z > 0) & (uv[:, 0] >= -0.5) & (uv[:, 1] >= -0.5) & (uv[:, 0] <= w - 0.5) & (uv[:, 1] <= h - 0.5)
    return np.flatnonzero(ok)


def triangulation_weight(angle_deg: np.ndarray, best_deg: float = 5.0) -> np.ndarray:
    """Weight of a shared point by the angle (degrees) between its two rays: 1 at ``best_deg``, a Gaussian
    of sigma 1 deg below it (little depth resolution) and of sigma 10 deg above (harder matching)."""
    a = np.asarray(angle_deg, np.float64)
    sigma = np.where(a <= best_deg, 1.0, 10.0)
    return np.exp(-((a - best_deg) ** 2) / (2 * sigma**2))


def select_neighbours(views: Sequence[View], points: np.ndarray, seen: Sequence[np.ndarray], ref: int,
                      count: int, best_deg: float = 5.0) -> list[int]:
    """The ``count`` best neighbours of view ``ref`` (indices into ``views``, best first).

    points (P, 3) sparse points; seen[i] (M_i,) indices of the points view i sees. Score of view j: the
    sum over the points both see of :func:`triangulation_weight` of the angle between the two rays; only
    views with a positive score (a shared point) qualify."""
    centres = np.stack([v.camera.center for v in views])
    return neighbours_by_centres(centres, points, seen, ref, count, None, best_deg)


def neighbours_by_centres(centres: np.ndarray, points: np.ndarray, seen: Sequence[np.ndarray], ref: int, count: int,
                          candidates: Sequence[int] | None = None, best_deg: float = 5.0) -> list[int]:
    """:func:`select_neighbours` from the camera centres (V, 3) alone, among ``candidates`` (indices; None: every
    other view): a survey of thousands of photos scores only the photos near each one."""
    mine = np.asarray(seen[ref])
    scores = []
    for j in (range(len(centres)) if candidates is None else candidates):
        if j == ref:
            continue
        shared = np.intersect1d(mine, seen[j], assume_unique=True)
        if len(shared) == 0:
            continue
        X = points[shared]
        a = X - centres[ref]
        b = X - centres[j]
        cosang = np.sum(a * b, 1) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
        angle = np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))
        score = float(triangulation_weight(angle, best_deg).sum())
        if score > 0:
            scores.append((score, j))
    scores.sort(key=lambda sj: (-sj[0], sj[1]))
    return [j for _, j in scores[:count]]


def depth_range(camera: Camera, points: np.ndarray, margin: float = 0.25, percentile: float = 1.0
                ) -> tuple[float, float] | None:
    """(near, far) of the sparse points (P, 3) the camera sees: their depths' ``percentile`` and
    ``100 - percentile`` percentiles, widened by ``margin`` (near / (1 + margin), far * (1 + margin));
    None when it sees fewer than 10."""
    idx = visible_points(camera, points)
    if len(idx) < 10:
        return None
    _, z = camera.project(points[idx])
    lo, hi = np.percentile(z, [percentile, 100 - percentile])
    if not hi > 0:
        return None
    lo = max(lo, hi * 1e-3)
    return float(lo / (1 + margin)), float(hi * (1 + margin))
