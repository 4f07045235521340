"""World coordinates for a reconstruction: WGS84 <-> UTM (pyproj) and a robust similarity between
the reconstruction's camera centres and their GPS positions.

The projected frame is the standard 6-degree UTM zone of the flight's centre (EPSG 326zz north of
the equator, 327zz south), x east and y north in metres, z the altitude as the device recorded it.
pyproj is imported when first used (it stays off the service's start path).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .evaluation import Sim3, umeyama
from .exif import GeoPoint

COLLINEAR_RATIO = 0.05
"""Camera positions whose second principal extent is below this fraction of the first lie on a line."""


def utm_epsg(lat: float, lon: float) -> int:
    """EPSG code of the WGS84 UTM zone (standard 6-degree zones) that holds (lat, lon) in degrees."""
    zone = int(np.floor((lon + 180.0) / 6.0)) % 60 + 1
    return (32600 if lat >= 0 else 32700) + zone


def _transformer(epsg: int, inverse: bool = False):
    from pyproj import Transformer

    return (Transformer.from_crs(epsg, 4326, always_xy=True) if inverse
            else Transformer.from_crs(4326, epsg, always_xy=True))


def to_projected(points: list[GeoPoint], epsg: int) -> np.ndarray:
    """WGS84 points -> (N, 3) float64 easting, northing (metres in ``epsg``), altitude (NaN when unknown)."""
    lon = np.array([p.lon for p in points], np.float64)
    lat = np.array([p.lat for p in points], np.float64)
    alt = np.array([np.nan if p.alt is None else p.alt for p in points], np.float64)
    e, n = _transformer(epsg).transform(lon, lat)
    return np.column_stack([e, n, alt])


def to_geographic(xyz: np.ndarray, epsg: int) -> list[GeoPoint]:
    """(N, 3) easting, northing, altitude in ``epsg`` -> WGS84 points."""
    xyz = np.asarray(xyz, np.float64).reshape(-1, 3)
    lon, lat = _transformer(epsg, inverse=True).transform(xyz[:, 0], xyz[:, 1])
    return [GeoPoint(float(a), float(o), float(z)) for a, o, z in zip(lat, lon, xyz[:, 2])]


@dataclass(frozen=True)
class SimilarityFit:
    """A similarity ``sim`` taking model points onto world points, fitted to the ``inliers`` (N,) bool;
    ``residuals`` (N,) metres for every pair under it; ``collinear``: the world positions lie on a line,
    so the roll about it came from ``up`` instead."""

    sim: Sim3
    inliers: np.ndarray
    residuals: np.ndarray
    threshold: float
    collinear: bool

    @property
    def rmse(self) -> float:
        """Root mean square residual of the inliers, metres."""
        r = self.residuals[self.inliers]
        return float(np.sqrt(np.mean(r * r))) if len(r) else float("nan")


def robust_similarity(src: np.ndarray, dst: np.ndarray, up: np.ndarray | None = None, min_threshold: float = 3.0,
                      iterations: int = 300, seed: int = 0) -> SimilarityFit:
    """Similarity from model points src (N, 3) to world points dst (N, 3), N >= 3, robust to outliers
    (GPS glitches): RANSAC over triples, inliers within ``max(min_threshold, 3 x`` the robust spread of
    the residuals``)`` metres, Umeyama's least squares on them, twice more on the refitted inliers.

    When dst lies on a line (a single straight flight line) the rotation about it is undetermined; then
    ``up`` (3,), a model direction that should point up (the ground's normal towards the cameras), fixes
    it: the fit is turned about the line until ``up`` maps as close to world +z as the line allows.
    Raises ValueError when fewer than 3 pairs are given or dst has no spread.
    """
    src = np.asarray(src, np.float64).reshape(-1, 3)
    dst = np.asarray(dst, np.float64).reshape(-1, 3)
    n = len(src)
    if n < 3:
        raise ValueError(f"a similarity needs three positions, got {n}")
    spread = np.linalg.svd(dst - dst.mean(0), compute_uv=False)
    if spread[0] < 1e-6:
        raise ValueError("the GPS positions do not move")
    collinear = bool(spread[1] < COLLINEAR_RATIO * spread[0])
    rng = np.random.default_rng(seed)
    best, best_count = None, -1
    sim0 = _fit(src, dst, up, collinear)
    thr = max(min_threshold, 3.0 * 1.4826 * float(np.median(_residuals(sim0, src, dst))))
    for _ in range(iterations if n > 3 else 0):
        pick = rng.choice(n, 3, replace=False)
        d = dst[pick]
        if np.linalg.norm(np.cross(d[1] - d[0], d[2] - d[0])) < 1e-3 * np.linalg.norm(d[1] - d[0]) ** 2 \
                and not collinear:
            continue
        try:
            sim = _fit(src[pick], d, up, collinear)
        except np.linalg.LinAlgError:
            continue
        count = int((_residuals(sim, src, dst) <= thr).sum())
        if count > best_count:
            best, best_count = sim, count
    sim = best if best is not None and best_count >= 3 else sim0
    inliers = _residuals(sim, src, dst) <= thr
    for _ in range(3):
        if inliers.sum() < 3:
            inliers[:] = True
        sim = _fit(src[inliers], dst[inliers], up, collinear)
        res = _residuals(sim, src, dst)
        thr = max(min_threshold, 3.0 * 1.4826 * float(np.median(res[inliers])))
        inliers = res <= thr
    return SimilarityFit(sim, inliers, _residuals(sim, src, dst), thr, collinear)


def _residuals(sim: Sim3, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    return np.linalg.norm(sim.apply(src) - dst, axis=1)


def _fit(src: np.ndarray, dst: np.ndarray, up: np.ndarray | None, collinear: bool) -> Sim3:
    sim = umeyama(src, dst)
    if not collinear or up is None:
        return sim
    # Turn about the line (through the centroid of dst) so that the model's up points as high as it can.
    centre = dst.mean(0)
    axis = np.linalg.svd(dst - centre, full_matrices=False)[2][0]
    u = sim.R @ (np.asarray(up, np.float64) / np.linalg.norm(up))
    z = np.array([0.0, 0.0, 1.0])
    u_perp = u - (u @ axis) * axis
    z_perp = z - (z @ axis) * axis
    if np.linalg.norm(u_perp) < 1e-9 or np.linalg.norm(z_perp) < 1e-9:
        return sim
    u_perp /= np.linalg.norm(u_perp)
    z_perp /= np.linalg.norm(z_perp)
    angle = np.arctan2(np.cross(u_perp, z_perp) @ axis, u_perp @ z_perp)
    Ra = _axis_rotation(axis, angle)
    return Sim3(sim.s, Ra @ sim.R, Ra @ (sim.t - centre) + centre)


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation (3, 3) by ``angle`` radians about the unit ``axis`` (3,) (Rodrigues)."""
    k = axis / np.linalg.norm(axis)
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def ground_up(points: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """The unit normal (3,) of the plane that best fits ``points`` (P, 3) (the ground, by least squares
    on the central 90 % of their spread), turned towards the mean of the camera centres (C, 3)."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    c = np.median(pts, axis=0)
    d = np.linalg.norm(pts - c, axis=1)
    core = pts[d <= np.percentile(d, 90)] if len(pts) > 10 else pts
    centred = core - core.mean(0)
    normal = np.linalg.eigh(centred.T @ centred)[1][:, 0]  # the direction of least spread
    if normal @ (np.asarray(centres, np.float64).mean(0) - core.mean(0)) < 0:
        normal = -normal
    return normal
