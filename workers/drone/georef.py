"""Putting a reconstruction into the world: a GPS position per frame (EXIF of stills, DJI telemetry for
video), a robust similarity from the camera centres to those positions in the local UTM zone, and the
model moved into that frame; or, without GPS, a level frame of its own.

The world frame after georeferencing ("local UTM"): x east, y north, z up, metres, with the origin at
``origin`` (UTM easting and northing rounded to 100 m, altitude 0) so that coordinates stay small for
float32 files (PLY); a UTM coordinate is ``local + origin``. Altitudes are those the drone recorded
(EXIF GPS altitude or the telemetry's, :attr:`Georeference.altitude` says which).

Without GPS ("arbitrary"): the ground plane fitted to the sparse points is made horizontal, z up towards
the cameras, origin at the ground's centre, units those of the reconstruction (no scale).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from . import bundle
from .camera_models import PinholeModel, pose_params, poses_from_params
from .evaluation import Sim3
from .exif import GeoPoint
from .geo import SimilarityFit, ground_up, robust_similarity, to_projected, utm_epsg
from .geometry import camera_centre
from .reconstruction import SparseModel

MIN_GPS_FRAMES = 3
MIN_GPS_SPREAD_M = 2.0


class GeoreferenceError(ValueError):
    """The GPS positions cannot place the reconstruction (too few, no spread); the message says why."""


@dataclass
class Georeference:
    """How a model was placed in the world (see the module docstring).

    ``sim`` takes the reconstruction's own frame to the world frame; ``epsg`` and ``origin`` (3,) define
    the world frame (None for an arbitrary one); ``frames`` (M,) the model frames with a GPS position,
    ``targets`` (M, 3) those positions in the world frame, ``fit`` the robust similarity (None for an
    arbitrary frame); ``source`` where the positions came from; ``altitude`` what their z means."""

    sim: Sim3
    epsg: int | None = None
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    frames: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    targets: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    fit: SimilarityFit | None = None
    source: str | None = None
    altitude: str | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def georeferenced(self) -> bool:
        """True for a world (UTM) frame, False for an arbitrary one."""
        return self.epsg is not None

    def describe(self) -> str:
        """The world frame in words (for file headers and the trajectory)."""
        if self.georeferenced:
            return (f"local UTM: EPSG:{self.epsg} easting/northing minus the origin {self.origin[:2].tolist()} m, "
                    f"z the recorded altitude in metres ({self.altitude})")
        return ("arbitrary: not georeferenced (no GPS); the ground made level, z up, origin at its centre, units of "
                "the reconstruction (no metric scale)")

    def report(self, model: SparseModel | None = None) -> dict[str, Any]:
        """JSON-able summary for report.json; with ``model`` (already in this frame) the camera-position
        error of the GPS frames as the model now stands."""
        out: dict[str, Any] = {"georeferenced": self.georeferenced, "frame": self.describe(), "notes": self.notes}
        if not self.georeferenced:
            return out
        fit = self.fit
        out.update({
            "epsg": self.epsg, "crs": f"WGS 84 / UTM zone {self.epsg % 100}{'N' if self.epsg < 32700 else 'S'}",
            "origin_utm": self.origin.tolist(), "gps_source": self.source, "altitude": self.altitude,
            "frames_with_gps": int(len(self.frames)), "inliers": int(fit.inliers.sum()),
            "outlier_frames": [int(f) for f in self.frames[~fit.inliers]],
            "inlier_threshold_m": fit.threshold, "scale": self.sim.s, "single_line": fit.collinear,
            "similarity_fit_rmse_m": fit.rmse,
        })
        if model is not None:
            err = self.camera_errors(model)[fit.inliers]
            out["camera_position_error_m"] = {
                "rmse": float(np.sqrt(np.mean((err ** 2).sum(1)))),
                "horizontal_rmse": float(np.sqrt(np.mean((err[:, :2] ** 2).sum(1)))),
                "vertical_rmse": float(np.sqrt(np.mean(err[:, 2] ** 2))),
                "max": float(np.linalg.norm(err, axis=1).max())}
        return out

    def camera_errors(self, model: SparseModel) -> np.ndarray:
        """(M, 3) camera centre minus GPS position (world frame, metres) of the GPS frames of ``model``,
        which must already be in this frame."""
        return np.stack([camera_centre(model.R[f], model.t[f]) for f in self.frames]) - self.targets


def frame_positions_from_exif(model: SparseModel, photos: dict[str, Any]) -> dict[int, GeoPoint]:
    """GPS positions of the model's frames from their photos' EXIF: ``photos`` maps a frame name to its
    :class:`~workers.drone.exif.PhotoMeta`."""
    out = {}
    for f, name in enumerate(model.frame_name):
        meta = photos.get(name)
        if meta is not None and meta.gps is not None:
            out[f] = meta.gps
    return out


def frame_positions_from_telemetry(model: SparseModel, telemetry) -> dict[int, GeoPoint]:
    """GPS positions of the model's (video) frames at their times, from a :class:`~workers.drone.srt.Telemetry`."""
    out = {}
    for f, t in enumerate(model.frame_time):
        if t is not None:
            pos = telemetry.position_at(float(t))
            if pos is not None:
                out[f] = pos
    return out


def georeference(model: SparseModel, positions: dict[int, GeoPoint], source: str, altitude: str,
                 origin: np.ndarray | None = None, epsg: int | None = None) -> Georeference:
    """Fit the robust similarity from the registered frames' camera centres to their GPS positions
    (:func:`workers.drone.geo.robust_similarity`, in the UTM zone of their centre unless ``epsg`` names one) and
    return it; the model is not changed (see :func:`apply`). ``origin`` (3,): the world frame's origin in UTM
    (default: their mean easting and northing rounded to 100 m; a survey's submodels share the survey's).
    Raises GeoreferenceError when fewer than three registered frames have a position or they span less than
    2 m."""
    frames = np.array(sorted(f for f in positions if model.registered[f]), np.int64)
    if len(frames) < MIN_GPS_FRAMES:
        raise GeoreferenceError(f"{len(frames)} registered frame(s) have a GPS position; georeferencing needs "
                                f"{MIN_GPS_FRAMES}")
    geo = [positions[int(f)] for f in frames]
    notes = []
    if epsg is None:
        epsg = survey_epsg(geo)
    xyz = to_projected(geo, epsg)
    if np.isnan(xyz[:, 2]).any():
        known = xyz[~np.isnan(xyz[:, 2]), 2]
        xyz[np.isnan(xyz[:, 2]), 2] = known.mean() if len(known) else 0.0
        notes.append("some or all GPS altitudes are missing: those frames were assumed at the mean altitude "
                     "(a level flight)")
        altitude = altitude + ", partly assumed"
    if origin is None:
        origin = survey_origin(xyz)
    targets = xyz - origin
    if np.linalg.norm(targets - targets.mean(0), axis=1).max() < MIN_GPS_SPREAD_M:
        raise GeoreferenceError("the GPS positions of the registered frames lie within "
                                f"{MIN_GPS_SPREAD_M:g} m of each other: too close to place the reconstruction")
    centres = np.stack([camera_centre(model.R[f], model.t[f]) for f in frames])
    up = ground_up(model.points, centres) if len(model.points) >= 10 else None
    fit = robust_similarity(centres, targets, up)
    if fit.collinear:
        notes.append("the GPS positions lie on one line: the roll about it comes from the ground plane")
    return Georeference(fit.sim, epsg, origin, frames, targets, fit, source, altitude, notes)


def survey_epsg(positions: list[GeoPoint]) -> int:
    """The UTM zone (EPSG code) of the positions' mean latitude and longitude."""
    return utm_epsg(float(np.mean([g.lat for g in positions])), float(np.mean([g.lon for g in positions])))


def survey_origin(xyz: np.ndarray) -> np.ndarray:
    """The world frame's origin (3,) for UTM positions (N, 3): their mean easting and northing rounded to 100 m,
    altitude 0."""
    return np.array([np.round(np.nanmean(xyz[:, 0]), -2), np.round(np.nanmean(xyz[:, 1]), -2), 0.0])


def level_frame(model: SparseModel) -> Georeference:
    """The arbitrary frame for a model without GPS: ground plane level, z up, origin at its centre."""
    reg = np.flatnonzero(model.registered)
    centres = np.stack([camera_centre(model.R[f], model.t[f]) for f in reg])
    up = ground_up(model.points, centres)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(up, z)
    c = float(up @ z)
    if np.linalg.norm(v) < 1e-12:
        R = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
        R = np.eye(3) + vx + vx @ vx / (1.0 + c)
    centre = np.median(model.points, axis=0)
    return Georeference(Sim3(1.0, R, -R @ centre),
                        notes=["no GPS positions: the products are in an arbitrary level frame without scale"])


def apply(model: SparseModel, sim: Sim3, world: str) -> None:
    """Move the model into the world frame ``X' = s R X + t`` in place (points, every pose, the poses of
    frames selection left out); ``world`` describes the new frame (the trajectory's convention)."""
    Rg, s, tg = sim.R, sim.s, sim.t
    model.points = sim.apply(model.points)
    reg = model.registered
    R_new = model.R[reg] @ Rg.T
    model.t[reg] = s * model.t[reg] - np.einsum("nij,j->ni", R_new, tg)
    model.R[reg] = R_new
    moved = []
    for view, loc in model.skipped:
        if loc.R is not None:
            R = loc.R @ Rg.T
            loc = replace(loc, R=R, t=s * loc.t - R @ tg)
        moved.append((view, loc))
    model.skipped = moved
    model.world = world


def gps_adjust(model: SparseModel, ref: Georeference, sigma_m: float, iterations: int = 30) -> bundle.BAResult:
    """Bundle adjustment of the georeferenced model with the GPS positions as a weak prior on the camera
    centres (``sigma_m`` metres per axis; only the similarity's inliers): the images keep the shape, the
    GPS its drift and bowl. Every pose and point is free (the GPS fixes the gauge); the lens stays as
    calibrated. Updates the model in place; returns the solver's result."""
    reg = np.flatnonzero(model.registered)
    pos = {int(f): i for i, f in enumerate(reg)}
    ci = np.array([pos[int(f)] for f in model.obs_frame], np.int64)
    target = np.full((len(reg), 3), np.nan)
    sigma = np.full(len(reg), np.inf)
    for f, xyz, ok in zip(ref.frames, ref.targets, ref.fit.inliers):
        if ok and int(f) in pos:
            target[pos[int(f)]] = xyz
            sigma[pos[int(f)]] = sigma_m
    res = bundle.solve(PinholeModel(model.K, len(reg)), pose_params(model.R[reg], model.t[reg]), model.points, ci,
                       model.obs_point, model.obs_xy, np.zeros((len(reg), 6), bool),
                       bundle.BAOptions(max_iterations=iterations, loss="cauchy", loss_scale=2.0),
                       centre_prior=bundle.CentrePrior(target, sigma))
    R, t = poses_from_params(res.params)
    model.R[reg], model.t[reg] = R, t
    model.points = res.points
    return res
