"""Ready-made scenes and camera rigs (world frame z up, metres)."""
from __future__ import annotations

import numpy as np

from workers.camera import Camera

from .scene import Box, Material, Plane, Scene, Sphere
from .textures import Checker, ColorNoise, Noise

DEFAULT_TARGET = (0.0, 0.0, 0.5)


def default_scene() -> Scene:
    """A studio like the paper's Fig. 3: a textured object group on a checker floor.

    Foreground (silhouette): a turned colour-noise box (0.5 x 0.5 x 0.6 m), a colour-noise sphere
    (r 0.25 m, with a mild specular highlight) on top of it and a small checker sphere beside it.
    Background: a grey checker ground plane (0.25 m cells) and a sky. Fits in a 1.2 m cube around
    ``DEFAULT_TARGET``.
    """
    return Scene((
        Plane(material=Material(Checker((90.0, 90.0, 90.0), (170.0, 170.0, 170.0), 0.25)), foreground=False),
        Box((0.0, 0.0, 0.3), (0.5, 0.5, 0.6), Material(ColorNoise(scale=0.08, octaves=5, seed=1, contrast=320.0)), yaw_deg=20.0),
        Sphere((0.0, 0.0, 0.85), 0.25, Material(ColorNoise(scale=0.06, octaves=5, seed=2, contrast=320.0), specular=0.25)),
        Sphere((0.38, -0.32, 0.15), 0.15, Material(Checker((30.0, 30.0, 200.0), (230.0, 230.0, 60.0), 0.05))),
    ))


def arc_camera(
    angle_deg: float, *, radius: float = 2.5, elevation: float = 1.3,
    target: tuple[float, float, float] = DEFAULT_TARGET, width: int = 640, height: int = 480,
    fov_deg: float = 50.0, name: str | None = None,
) -> Camera:
    """A camera on a horizontal circle of ``radius`` about ``target``, at height ``elevation``.

    ``angle_deg`` 0 puts it on the -y side looking towards +y; positive angles go anticlockwise
    seen from above (towards +x). It looks at ``target`` with z up in the image.
    """
    a = np.radians(angle_deg)
    eye = np.array([target[0] + radius * np.sin(a), target[1] - radius * np.cos(a), elevation])
    return Camera.look_at(name or f"arc{angle_deg:+.2f}", eye, target, (0.0, 0.0, 1.0), fov_deg, width, height)


def default_arc_rig(
    n: int = 10, *, arc_deg: float = 90.0, radius: float = 2.5, elevation: float = 1.3,
    target: tuple[float, float, float] = DEFAULT_TARGET, width: int = 640, height: int = 480,
    fov_deg: float = 50.0, prefix: str = "cam",
) -> list[Camera]:
    """``n`` cameras evenly spread over ``arc_deg`` degrees of a circle around the object (Fig. 3).

    Names ``cam00`` .. ``cam{n-1}``; angles from ``-arc_deg/2`` to ``+arc_deg/2`` (see arc_camera).
    """
    if n < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    angles = np.linspace(-arc_deg / 2, arc_deg / 2, n) if n > 1 else np.zeros(1)
    return [arc_camera(float(a), radius=radius, elevation=elevation, target=target, width=width, height=height,
                       fov_deg=fov_deg, name=f"{prefix}{i:02d}") for i, a in enumerate(angles)]


def arc_angles(n: int = 10, arc_deg: float = 90.0) -> np.ndarray:
    """The angles (degrees) of :func:`default_arc_rig`'s cameras, (n,) float64."""
    return np.linspace(-arc_deg / 2, arc_deg / 2, n) if n > 1 else np.zeros(1)


def camera_gains(n: int, spread: float = 0.06, seed: int = 0) -> list[tuple[float, float, float]]:
    """Per-camera (B, G, R) colour gains in ``1 ± spread``: the exposure and white-balance
    differences of real cameras, which make a hard switch between cameras visible."""
    rng = np.random.default_rng(seed)
    g = 1 + rng.uniform(-spread, spread, size=(n, 3))
    return [tuple(map(float, row)) for row in g]


def city_scene(
    seed: int = 0, *, extent: float = 200.0, n_buildings: int = 40, min_size: float = 8.0,
    max_size: float = 25.0, max_height: float = 25.0, ground_scale: float = 6.0, ground_octaves: int = 7,
) -> Scene:
    """Ground plus buildings, for synthetic drone flights.

    A ground plane z = 0 with a fine colour-noise texture (features from ``ground_scale`` metres down to
    ``ground_scale / 2**(ground_octaves-1)``) and ``n_buildings`` boxes (foreground) of random
    footprint in [min_size, max_size] m, height in [3, max_height] m and yaw, centred in a square of
    side ``extent`` around the origin, each with its own noise texture. Deterministic in ``seed``.
    """
    rng = np.random.default_rng(seed)
    objects: list = [Plane(material=Material(ColorNoise(scale=ground_scale, octaves=ground_octaves,
                                                         seed=seed * 101 + 7, contrast=170.0)))]
    for k in range(n_buildings):
        sx, sy = rng.uniform(min_size, max_size, size=2)
        hz = rng.uniform(3.0, max_height)
        cx, cy = rng.uniform(-extent / 2, extent / 2, size=2)
        tone_a = tuple(float(v) for v in rng.uniform(30, 110, size=3))
        tone_b = tuple(float(v) for v in rng.uniform(150, 240, size=3))
        tex = Noise(tone_a, tone_b, scale=2.0, octaves=5, seed=seed * 1000 + k)
        objects.append(Box((float(cx), float(cy), hz / 2), (float(sx), float(sy), float(hz)), Material(tex),
                           yaw_deg=float(rng.uniform(0, 90))))
    return Scene(tuple(objects))
