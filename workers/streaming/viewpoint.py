"""Virtual cameras from viewer messages: orbits around a rig, look-at poses and raw poses.

The orbit frame of a rig (:class:`OrbitFrame`) is derived from its cameras: the target is the rig's
focus point, "up" is the cameras' mean image-up direction (OpenCV's -y), azimuth 0 is the cameras'
mean direction from the target, and the home elevation and distance are the cameras' means.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from workers.camera import Camera, CameraError, interpolate
from workers.sweep.rig import Rig, RigError

from .params import Orbit, ViewPose


@dataclass(frozen=True)
class OrbitFrame:
    """Reference frame of orbits around a rig (world coordinates, metres, degrees).

    target (3,), up (3,) unit, forward (3,) unit horizontal direction of azimuth 0, side (3,) =
    up x forward (azimuth +90), home ``elevation`` and ``distance``, and each rig camera's
    ``azimuths`` (N,) and ``elevations`` (N,).
    """

    target: np.ndarray
    up: np.ndarray
    forward: np.ndarray
    side: np.ndarray
    elevation: float
    distance: float
    azimuths: np.ndarray
    elevations: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description (what the viewer page starts from)."""
        return {
            "target": self.target.tolist(), "up": self.up.tolist(), "forward": self.forward.tolist(),
            "elevation": self.elevation, "distance": self.distance,
            "camera_azimuths": self.azimuths.tolist(), "camera_elevations": self.elevations.tolist(),
        }

    def eye(self, azimuth: float, elevation: float, distance: float, target: np.ndarray) -> np.ndarray:
        """Eye position (3,) of an orbit camera."""
        a, e = np.radians(azimuth), np.radians(elevation)
        horizontal = np.cos(a) * self.forward + np.sin(a) * self.side
        return target + distance * (np.cos(e) * horizontal + np.sin(e) * self.up)


def orbit_frame(rig: Rig) -> OrbitFrame:
    """The :class:`OrbitFrame` of ``rig``."""
    target = rig.focus_point()
    up = rig_up(rig)
    offsets = rig.centers() - target
    flat = offsets - np.outer(offsets @ up, up)
    mean_flat = flat.mean(axis=0)
    if np.linalg.norm(mean_flat) < 1e-9:  # cameras straight above/below: any horizontal direction
        mean_flat = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    forward = mean_flat / np.linalg.norm(mean_flat)
    side = np.cross(up, forward)
    dist = np.linalg.norm(offsets, axis=1)
    elevations = np.degrees(np.arcsin(np.clip((offsets @ up) / np.maximum(dist, 1e-12), -1, 1)))
    azimuths = np.degrees(np.arctan2(flat @ side, flat @ forward))
    return OrbitFrame(target, up, forward, side, float(np.mean(elevations)), float(np.mean(dist)),
                      azimuths, elevations)


def rig_up(rig: Rig) -> np.ndarray:
    """The world direction (3,) unit the rig shows upwards.

    Cameras set up level have their image x axes perpendicular to up: with x axes spanning a fan,
    up is the direction most perpendicular to all of them; with (nearly) parallel x axes, the
    cameras' mean image-up (-y) with its x component removed. Signed to agree with the mean -y."""
    xs = np.stack([c.R[0] for c in rig.cameras])
    mean_up = -np.mean([c.R[1] for c in rig.cameras], axis=0)
    values, vectors = np.linalg.eigh(xs.T @ xs)
    if values[1] > 0.05 * len(xs):
        up = vectors[:, 0]
    else:
        x = vectors[:, 2]
        up = mean_up - (mean_up @ x) * x
    if not np.linalg.norm(up) > 1e-9:
        return np.array([0.0, 0.0, 1.0])
    up = up / np.linalg.norm(up)
    return up if up @ mean_up >= 0 else -up


def orbit_camera(frame: OrbitFrame, orbit: Orbit, fov: float, size: tuple[int, int],
                 name: str = "virtual") -> Camera:
    """The camera of an orbit (missing fields from the frame's home), image ``size`` = (w, h)."""
    elevation = frame.elevation if orbit.elevation is None else orbit.elevation
    distance = frame.distance if orbit.distance is None else orbit.distance
    target = frame.target if orbit.target is None else np.asarray(orbit.target, np.float64)
    eye = frame.eye(orbit.azimuth, float(np.clip(elevation, -89.0, 89.0)), distance, target)
    return Camera.look_at(name, eye, target, frame.up, fov, size[0], size[1])


def virtual_camera(view: ViewPose, frame: OrbitFrame, size: tuple[int, int], name: str = "virtual") -> Camera:
    """The virtual camera of ``view`` at image ``size`` = (w, h); RigError for an unusable pose."""
    w, h = size
    try:
        if view.pose is not None:
            K = _intrinsics(view.fov, w, h)
            return Camera(name, K, np.array(view.pose.R), np.array(view.pose.t), w, h)
        if view.look_at is not None:
            up = frame.up if view.look_at.up is None else np.asarray(view.look_at.up, np.float64)
            return Camera.look_at(name, view.look_at.eye, view.look_at.target, up, view.fov, w, h)
        return orbit_camera(frame, view.orbit or Orbit(), view.fov, size, name)
    except CameraError as exc:
        raise RigError("virtual", exc.field, str(exc).split(": ", 2)[-1]) from None


def _intrinsics(fov: float, w: int, h: int) -> np.ndarray:
    f = 0.5 * w / np.tan(np.radians(fov) / 2)
    return np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])


def path_cameras(keys: list[ViewPose], ats: list[float] | None, frame: OrbitFrame, size: tuple[int, int],
                 count: int) -> list[Camera]:
    """``count`` cameras along key poses at parameters ``ats`` (None: evenly spaced in [0, 1]).

    Orbit keys are interpolated in orbit parameters (the path follows the arc); mixed or other keys
    by camera interpolation (slerp of rotation, lerp of centre and intrinsics).
    """
    m = len(keys)
    ats = ats if ats is not None else list(np.linspace(0.0, 1.0, m))
    out = []
    for i in range(count):
        s = i / (count - 1) if count > 1 else 0.0
        s = min(max(s, ats[0]), ats[-1])
        j = min(int(np.searchsorted(ats, s, side="right")) - 1, m - 2)
        j = max(j, 0)
        span = ats[j + 1] - ats[j]
        u = (s - ats[j]) / span if span > 0 else 0.0
        out.append(_between(keys[j], keys[j + 1], u, frame, size, f"path{i:05d}"))
    return out


def _between(a: ViewPose, b: ViewPose, u: float, frame: OrbitFrame, size: tuple[int, int], name: str) -> Camera:
    if a.orbit is not None and b.orbit is not None:
        oa, ob = _orbit_values(a.orbit, frame), _orbit_values(b.orbit, frame)
        mix = [(1 - u) * np.asarray(x) + u * np.asarray(y) for x, y in zip(oa, ob)]
        orbit = Orbit(azimuth=float(mix[0]), elevation=float(mix[1]), distance=float(mix[2]),
                      target=tuple(float(v) for v in mix[3]))
        return orbit_camera(frame, orbit, (1 - u) * a.fov + u * b.fov, size, name)
    ca, cb = virtual_camera(a, frame, size), virtual_camera(b, frame, size)
    return interpolate(ca, cb, u, name=name)


def _orbit_values(o: Orbit, frame: OrbitFrame) -> tuple[float, float, float, np.ndarray]:
    return (o.azimuth, frame.elevation if o.elevation is None else o.elevation,
            frame.distance if o.distance is None else o.distance,
            frame.target if o.target is None else np.asarray(o.target, np.float64))
