"""A synthetic mapping flight with exact answers: a lawnmower pattern of nadir stills over textured
ground with buildings and trees, geotagged JPEGs as a drone writes them, and the true orthophoto and
surface model of the same ground.

World frame: x east, y north, z up, metres (as :mod:`workers.synth`); ``origin`` places it in a UTM zone
(the GPS EXIF of the stills is that position in WGS84).

- ``survey_scene(seed, extent)``: ground plane (colour noise, detail from 4 m down to 0.25 m: about
  twice the ground pixel of a flight at 60 m, what a lens resolves), box buildings (4-12 m tall),
  spherical tree crowns.
- ``survey_cameras(...)``: parallel flight lines, alternating direction with a fixed heading (as mapping
  apps fly), forward and side overlap from the footprint, a small attitude jitter (a real gimbal is never
  exactly nadir), optional lens distortion.
- ``true_orthophoto(scene, grid...)``: the scene seen straight from above, each cell the average colour
  of its area, and the height of the top surface at each cell's centre (the true DSM).
- ``write_geotagged_stills(...)``: JPEGs with GPS (WGS84 latitude, longitude, altitude) and focal-length
  EXIF, named in flight order.
"""
from __future__ import annotations

import math
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from workers.camera import Camera

from .flight import visible_part
from .raycast import _cast
from .scene import Box, Material, Plane, Scene, Sphere
from .textures import ColorNoise, Noise

_FAR = 1.0e6  # metres: the orthographic camera's height (relief displacement 20 m x 150 m / 1e6 = 3 mm)


def survey_scene(seed: int = 0, extent: float = 160.0, n_buildings: int = 14, n_trees: int = 24) -> Scene:
    """Ground z = 0 with colour-noise detail from 4 m down to 0.25 m, ``n_buildings`` boxes (4-12 m tall,
    6-14 m footprints, turned) and ``n_trees`` crowns (radius 2-4 m, 3-6 m up), in a square of side
    ``extent`` around the origin; deterministic in ``seed``."""
    rng = np.random.default_rng(seed)
    objects: list = [Plane(material=Material(ColorNoise(scale=4.0, octaves=5, seed=seed * 101 + 5, contrast=260.0)))]
    half = extent / 2
    for k in range(n_buildings):
        sx, sy = rng.uniform(6.0, 14.0, size=2)
        hz = rng.uniform(4.0, 12.0)
        cx, cy = rng.uniform(-half, half, size=2)
        dark = tuple(float(v) for v in rng.uniform(30, 100, size=3))
        light = tuple(float(v) for v in rng.uniform(160, 240, size=3))
        objects.append(Box((float(cx), float(cy), hz / 2), (float(sx), float(sy), float(hz)),
                           Material(Noise(dark, light, scale=4.0, octaves=4, seed=seed * 1000 + k)),
                           yaw_deg=float(rng.uniform(0, 90))))
    for k in range(n_trees):
        r = rng.uniform(2.0, 4.0)
        cx, cy = rng.uniform(-half, half, size=2)
        tex = Noise((25.0, 80.0, 25.0), (90.0, 190.0, 110.0), scale=3.0, octaves=4, seed=seed * 2000 + k)
        objects.append(Sphere((float(cx), float(cy), float(r + rng.uniform(1.0, 2.0))), float(r), Material(tex)))
    return Scene(tuple(objects))


def survey_cameras(area: tuple[float, float], altitude: float, *, fov_deg: float = 70.0, width: int = 640,
                   height: int = 480, forward_overlap: float = 0.75, side_overlap: float = 0.65,
                   jitter_deg: float = 1.0, dist: tuple[float, ...] | None = None, seed: int = 0) -> list[Camera]:
    """Nadir cameras over ``area`` (x extent, y extent) metres centred on the origin, at ``altitude``.

    Lines run along x, one after the other from south to north, alternating direction at a fixed heading
    (the image's top points east on every line, its long side across the lines). Spacing from the footprint and the
    overlaps; each camera turned by a random rotation of ``jitter_deg`` standard deviation per axis;
    ``dist``: OpenCV distortion coefficients of every camera's lens. Names ``shot0000`` ...
    """
    rng = np.random.default_rng(seed)
    half_w = altitude * math.tan(math.radians(fov_deg) / 2)  # across-track half footprint (image width)
    half_h = half_w * height / width
    step_along = 2 * half_h * (1 - forward_overlap)
    step_across = 2 * half_w * (1 - side_overlap)
    n_lines = max(2, int(math.ceil(area[1] / step_across)) + 1)
    n_along = max(2, int(math.ceil(area[0] / step_along)) + 1)
    ys = (np.arange(n_lines) - (n_lines - 1) / 2) * step_across
    xs = (np.arange(n_along) - (n_along - 1) / 2) * step_along
    cams = []
    for li, y in enumerate(ys):
        for x in (xs if li % 2 == 0 else xs[::-1]):
            eye = np.array([x, y, altitude])
            cam = Camera.look_at(f"shot{len(cams):04d}", eye, eye - [0.0, 0.0, altitude], up=(1.0, 0.0, 0.0),
                                 fov_deg=fov_deg, width=width, height=height)
            turn = _rotation(rng.normal(0.0, math.radians(jitter_deg), 3))
            R = turn @ cam.R
            cams.append(Camera(cam.name, cam.K, R, -R @ eye, width, height,
                               None if dist is None else np.asarray(dist, np.float64)))
    return cams


def _rotation(v: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(v))
    if th < 1e-15:
        return np.eye(3)
    return cv2.Rodrigues(np.asarray(v, np.float64).reshape(3, 1))[0]


def true_orthophoto(scene: Scene, x0: float, y0: float, gsd: float, width: int, height: int,
                    supersample: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """The scene seen straight from above over the grid whose top-left corner is (x0, y0) (cells of
    ``gsd`` metres, rows from north to south): the image (height, width, 3) uint8 BGR, each cell the mean of
    supersample^2 rays spread over its area, and the true DSM (height, width) float64, the height of the
    top surface under each cell's centre (-inf where nothing is below).

    The rays come from a pinhole camera 1000 km up (parallel within 3 mm of relief displacement over the
    grid), cast in float64, against the objects over the grid only (a survey's scene has hundreds)."""
    centre = np.array([x0 + 0.5 * width * gsd, y0 - 0.5 * height * gsd, _FAR])
    f = _FAR / gsd
    K = np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])
    R = np.diag([1.0, -1.0, -1.0])  # x east, y (image down) south, z (forward) down
    cam = Camera("orthographic", K, R, -R @ centre, width, height)
    scene = visible_part(scene, cam)
    depth, _, _ = _cast(scene, cam, 1)
    _, _, colour = _cast(scene, cam, supersample)
    image = colour.reshape(height, supersample, width, supersample, 3).mean(axis=(1, 3))
    return np.clip(np.rint(image), 0, 255).astype(np.uint8), _FAR - depth


def write_geotagged_stills(folder: str | Path, frames: list[np.ndarray], cameras: list[Camera], epsg: int,
                           origin: tuple[float, float, float], focal_35mm: float | None = None,
                           gps_noise_m: float = 0.0, seed: int = 0, quality: int = 95,
                           full_chroma: bool = True) -> list[Path]:
    """Write ``frames`` (H, W, 3) uint8 BGR as ``<camera name>.jpg`` in ``folder`` with EXIF: Make/Model
    'sweepcast'/'SYNTH', GPS latitude/longitude/altitude of the camera centre (+ ``origin``, in ``epsg``,
    plus Gaussian noise of ``gps_noise_m`` per axis), FocalLengthIn35mmFilm when given (mm, the diagonal
    rule; an integer in EXIF as cameras write it). JPEG ``quality``; ``full_chroma``: 4:4:4 (else the
    codec's 4:2:0, which halves the colour resolution). Returns the paths."""
    import piexif
    from pyproj import Transformer

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    to_wgs84 = Transformer.from_crs(epsg, 4326, always_xy=True)
    rng = np.random.default_rng(seed)
    paths = []
    for img, cam in zip(frames, cameras):
        c = cam.center + np.asarray(origin, np.float64) + rng.normal(0.0, gps_noise_m, 3)
        lon, lat = to_wgs84.transform(c[0], c[1])
        gps = {piexif.GPSIFD.GPSLatitudeRef: b"N" if lat >= 0 else b"S", piexif.GPSIFD.GPSLatitude: _dms(abs(lat)),
               piexif.GPSIFD.GPSLongitudeRef: b"E" if lon >= 0 else b"W", piexif.GPSIFD.GPSLongitude: _dms(abs(lon)),
               piexif.GPSIFD.GPSAltitudeRef: 0 if c[2] >= 0 else 1,
               piexif.GPSIFD.GPSAltitude: _rational(abs(float(c[2])), 1000)}
        exif = {piexif.ExifIFD.FocalLengthIn35mmFilm: int(round(focal_35mm))} if focal_35mm else {}
        zeroth = {piexif.ImageIFD.Make: b"sweepcast", piexif.ImageIFD.Model: b"SYNTH"}
        options = [cv2.IMWRITE_JPEG_QUALITY, quality]
        if full_chroma:
            options += [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444]
        ok, jpg = cv2.imencode(".jpg", img, options)
        if not ok:  # pragma: no cover
            raise RuntimeError("JPEG encoding failed")
        path = folder / f"{cam.name}.jpg"
        piexif.insert(piexif.dump({"0th": zeroth, "Exif": exif, "GPS": gps}), jpg.tobytes(), str(path))
        paths.append(path)
    return paths


def _rational(value: float, denominator: int) -> tuple[int, int]:
    return int(round(value * denominator)), denominator


def _dms(deg: float) -> tuple[tuple[int, int], tuple[int, int], tuple[int, int]]:
    """Degrees -> EXIF ((d, 1), (m, 1), (s * 1e6, 1e6)) (micro-arcseconds: ~3e-8 m steps)."""
    d = int(deg)
    m = int((deg - d) * 60)
    s = Fraction((deg - d - m / 60) * 3600).limit_denominator(1_000_000)
    return (d, 1), (m, 1), (s.numerator, s.denominator)
