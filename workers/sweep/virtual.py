"""Virtual cameras: from a pose, from look-at + up + field of view, between two rig cameras,
along a path through rig cameras, on a sphere around a target (and a triangular lattice of such
viewpoints: a two-dimensional rig), and from a command-line pose specification."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from workers.camera import Camera, CameraError, interpolate

from .rig import Rig, RigError


def from_pose(
    R: np.ndarray, center: np.ndarray, *, like: Camera, name: str = "virtual", size: tuple[int, int] | None = None,
) -> Camera:
    """A virtual camera with rotation ``R`` (3, 3, world-to-camera) at ``center`` (3,), with the
    intrinsics of ``like`` (a rig camera), rescaled to ``size`` = (width, height) when given."""
    cam = Camera.from_center(name, like.K, R, center, like.width, like.height)
    return _resized(cam, size)


def look_at(
    eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0), *, fov_deg: float = 50.0,
    size: tuple[int, int] = (640, 480), name: str = "virtual",
) -> Camera:
    """A virtual camera at ``eye`` looking at ``target``, ``up`` shown upwards, horizontal field of
    view ``fov_deg``, image ``size`` = (width, height)."""
    return Camera.look_at(name, eye, target, up, fov_deg, size[0], size[1])


def between(rig: Rig, a: str | int, b: str | int, s: float, *, size: tuple[int, int] | None = None,
            name: str | None = None) -> Camera:
    """The camera a fraction ``s`` in [0, 1] of the way from rig camera ``a`` to ``b`` (slerp of
    rotation, lerp of centre and intrinsics), optionally rescaled to ``size``."""
    if not 0.0 <= s <= 1.0:
        raise RigError(None, "s", f"must be in [0, 1], got {s}")
    ca, cb = rig[a], rig[b]
    return _resized(interpolate(ca, cb, s, name=name or f"{ca.name}~{cb.name}@{s:.3f}"), size)


def path(rig: Rig, names: list[str | int], steps_per_leg: int, *, size: tuple[int, int] | None = None) -> list[Camera]:
    """Cameras moving through the rig cameras ``names`` in order, ``steps_per_leg`` per leg
    (the last camera included once): a fly-through or a camera-switch sweep."""
    if len(names) < 2 or steps_per_leg < 1:
        raise RigError(None, "path", "needs at least two cameras and one step per leg")
    out = []
    for k in range(len(names) - 1):
        for step in range(steps_per_leg):
            out.append(between(rig, names[k], names[k + 1], step / steps_per_leg, size=size, name=f"path{len(out):04d}"))
    out.append(between(rig, names[-2], names[-1], 1.0, size=size, name=f"path{len(out):04d}"))
    return out


def sphere_camera(
    azimuth_deg: float, elevation_deg: float, *, radius: float, target: np.ndarray, size: tuple[int, int] = (640, 480),
    fov_deg: float = 50.0, name: str = "virtual",
) -> Camera:
    """A camera ``radius`` metres from ``target`` (3,), looking at it with z up in the image, at
    ``azimuth_deg`` about the z axis (0 on the -y side, positive towards +x, as workers.synth's arc
    cameras) and ``elevation_deg`` above the horizontal plane through ``target``; ``size`` = (width,
    height), horizontal field of view ``fov_deg``. Virtual views anywhere over a dome of cameras."""
    a, e = np.radians(azimuth_deg), np.radians(elevation_deg)
    eye = np.asarray(target, np.float64) + radius * np.array([np.cos(e) * np.sin(a), -np.cos(e) * np.cos(a), np.sin(e)])
    return look_at(eye, target, (0.0, 0.0, 1.0), fov_deg=fov_deg, size=size, name=name)


def sphere_lattice(spacing_deg: float, rows: int, per_row: int, elevation0_deg: float) -> np.ndarray:
    """(azimuth, elevation) in degrees, (rows * per_row - rows // 2, 2) float64, of a triangular lattice of
    viewpoints on a sphere with neighbours ``spacing_deg`` apart (seen from the centre, to first order):
    rows ``spacing_deg * sqrt(3) / 2`` apart in elevation from ``elevation0_deg`` up, ``per_row`` viewpoints
    in even rows and one fewer, offset by half a step, in odd rows; azimuth steps widened by 1 / cos(elevation),
    centred on azimuth 0. A two-dimensional camera rig: every three mutual neighbours make a triangle whose
    centre is a triple point, where three one-camera regions meet (the case ``kojima_k`` is for)."""
    if rows < 1 or per_row < 2 or not spacing_deg > 0:
        raise RigError(None, "lattice", "needs rows >= 1, per_row >= 2 and a positive spacing")
    out = []
    for r in range(rows):
        el = elevation0_deg + r * spacing_deg * np.sqrt(3) / 2
        step = spacing_deg / np.cos(np.radians(el))
        n = per_row - (r % 2)
        for k in range(n):
            out.append((float((k - (n - 1) / 2) * step), float(el)))
    return np.array(out)


def parse_pose(spec: str, rig: Rig, *, size: tuple[int, int] | None = None, fov_deg: float = 50.0) -> Camera:
    """A virtual camera from a command-line specification:

    - ``NAME``: the rig camera of that name;
    - ``A:B:S``: between rig cameras A and B at fraction S;
    - ``lookat:EX,EY,EZ:TX,TY,TZ[:UX,UY,UZ]``: eye, target, up (default z up), with ``fov_deg``;
    - a path to a JSON file holding one camera (our rig JSON's camera object).

    ``size`` = (width, height) rescales rig-derived cameras and sizes look-at ones (default 640x480).
    """
    if spec.startswith("lookat:"):
        parts = spec.split(":")[1:]
        if len(parts) not in (2, 3):
            raise RigError(None, "pose", "lookat needs 'lookat:EX,EY,EZ:TX,TY,TZ[:UX,UY,UZ]'")
        vecs = [_vec3(p) for p in parts]
        up = vecs[2] if len(vecs) == 3 else np.array([0.0, 0.0, 1.0])
        try:
            return look_at(vecs[0], vecs[1], up, fov_deg=fov_deg, size=size or (640, 480))
        except CameraError as e:
            raise RigError(None, "pose", str(e)) from None
    if spec.endswith(".json") and Path(spec).is_file():
        try:
            d = json.loads(Path(spec).read_text())
        except json.JSONDecodeError as e:
            raise RigError(None, "pose", f"{spec} is not valid JSON ({e})") from None
        return _resized(Camera.from_dict(d, name="virtual"), size)
    if spec.count(":") == 2:
        a, b, s = spec.split(":")
        try:
            frac = float(s)
        except ValueError:
            raise RigError(None, "pose", f"'{s}' in '{spec}' is not a number") from None
        return between(rig, a, b, frac, size=size)
    return _resized(rig[spec].renamed("virtual"), size)


def _vec3(text: str) -> np.ndarray:
    try:
        v = np.array([float(t) for t in text.split(",")])
    except ValueError:
        raise RigError(None, "pose", f"'{text}' is not three comma-separated numbers") from None
    if v.shape != (3,):
        raise RigError(None, "pose", f"'{text}' is not three comma-separated numbers")
    return v


def _resized(cam: Camera, size: tuple[int, int] | None) -> Camera:
    if size is None or (cam.width, cam.height) == tuple(size):
        return cam
    w, h = size
    if abs(w / cam.width - h / cam.height) > 1e-6 * max(w / cam.width, 1):
        # different aspect: scale each axis on its own, keeping the pixel-centre convention
        K = cam.K.copy()
        sx, sy = w / cam.width, h / cam.height
        K[0, 0] *= sx
        K[0, 1] *= sx
        K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
        K[1, 1] *= sy
        K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
        return Camera(cam.name, K, cam.R, cam.t, w, h)
    return cam.scaled(w / cam.width)
