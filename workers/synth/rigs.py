"""Ready-made scenes and camera rigs (world frame z up, metres)."""
from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from workers.camera import Camera

from .scene import Box, Material, Plane, Scene, Sphere
from .textures import BoxPicture, Checker, ColorNoise, Noise, Planks, Solid, SpherePicture

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


def occluder_scene() -> Scene:
    """A textureless occluder: a flat red box (0.45 x 0.45 x 0.7 m, one colour, shaded per face) standing before a
    colour-noise wall 1 m behind it, on a grey checker floor; nothing is foreground but the box. Seen by
    :func:`default_arc_rig` cameras, the box hides strips of the wall and floor from each, and every plane through
    it matches equally well in its middle: the case where a depth check that trusts ties, or colour from a camera
    that sees the box in front, fails (tests/sweep/test_sweep_occluder.py, benchmarks/sweep/viewer.py)."""
    return Scene((
        Plane(material=Material(Checker((90.0, 90.0, 90.0), (170.0, 170.0, 170.0), 0.2)), foreground=False),
        Plane(point=(0.0, 0.9, 0.0), normal=(0.0, -1.0, 0.0),
              material=Material(ColorNoise(scale=0.06, octaves=5, seed=4, contrast=320.0)), foreground=False),
        Box((0.0, -0.1, 0.35), (0.45, 0.45, 0.7), Material(Solid((40.0, 60.0, 200.0)))),
    ))


def arc_camera(
    angle_deg: float, *, radius: float = 2.5, elevation: float = 1.3,
    target: tuple[float, float, float] = DEFAULT_TARGET, width: int = 640, height: int = 480,
    fov_deg: float = 50.0, name: str | None = None, dist: tuple[float, ...] | None = None,
) -> Camera:
    """A camera on a horizontal circle of ``radius`` about ``target``, at height ``elevation``.

    ``angle_deg`` 0 puts it on the -y side looking towards +y; positive angles go anticlockwise
    seen from above (towards +x). It looks at ``target`` with z up in the image. ``dist``: OpenCV lens
    distortion coefficients (k1, k2, p1, p2[, k3]) of its lens (None: an ideal pinhole).
    """
    a = np.radians(angle_deg)
    eye = np.array([target[0] + radius * np.sin(a), target[1] - radius * np.cos(a), elevation])
    cam = Camera.look_at(name or f"arc{angle_deg:+.2f}", eye, target, (0.0, 0.0, 1.0), fov_deg, width, height)
    return cam if dist is None else Camera(cam.name, cam.K, cam.R, cam.t, width, height, dist)


def default_arc_rig(
    n: int = 10, *, arc_deg: float = 90.0, radius: float = 2.5, elevation: float = 1.3,
    target: tuple[float, float, float] = DEFAULT_TARGET, width: int = 640, height: int = 480,
    fov_deg: float = 50.0, prefix: str = "cam", dist: tuple[float, ...] | None = None,
) -> list[Camera]:
    """``n`` cameras evenly spread over ``arc_deg`` degrees of a circle around the object (Fig. 3).

    Names ``cam00`` .. ``cam{n-1}``; angles from ``-arc_deg/2`` to ``+arc_deg/2`` (see arc_camera,
    also for ``dist``).
    """
    if n < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    angles = np.linspace(-arc_deg / 2, arc_deg / 2, n) if n > 1 else np.zeros(1)
    return [arc_camera(float(a), radius=radius, elevation=elevation, target=target, width=width, height=height,
                       fov_deg=fov_deg, name=f"{prefix}{i:02d}", dist=dist) for i, a in enumerate(angles)]


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


# --- the photographic studio --------------------------------------------------------------------
PHOTO_CREDITS = (
    "china.jpg and flower.jpg: scikit-learn's sample images (sklearn.datasets.load_sample_image), "
    "CC BY 2.0 (https://creativecommons.org/licenses/by/2.0/), by danielbuechele and vultilion on Flickr"
)
"""Where the studio's photographs come from and their licence (they ship with scikit-learn, a dependency)."""


@lru_cache(maxsize=None)
def sample_photo(name: str) -> np.ndarray:
    """One of scikit-learn's sample photographs ("china.jpg", "flower.jpg"; :data:`PHOTO_CREDITS`) as
    (427, 640, 3) uint8 BGR (read-only; cached)."""
    from sklearn.datasets import load_sample_image

    img = np.ascontiguousarray(load_sample_image(name)[:, :, ::-1])
    img.setflags(write=False)
    return img


def _fitted(img: np.ndarray, width: int) -> np.ndarray:
    """``img`` resized (area-averaged) to ``width`` px wide, float32: about one texel per pixel seen."""
    h = max(2, round(img.shape[0] * width / img.shape[1]))
    return cv2.resize(img, (width, h), interpolation=cv2.INTER_AREA).astype(np.float32)


def studio_scene() -> Scene:
    """A photographic studio for the first-run demo: a lit plank stage in a green-screen studio with
    objects wrapped in photographs (:data:`PHOTO_CREDITS`).

    Foreground (silhouette): a plank stage (1.8 x 1.6 x 0.08 m, grain from china.jpg), a turned box
    (0.5 x 0.5 x 0.6 m) wrapped in flower.jpg, a sphere (r 0.25 m, china.jpg wrapped round it, a mild
    highlight) on top of it and a small flower.jpg ball (r 0.15 m) beside it on the stage. Background:
    a dark chroma-green floor and walls (the sky), as in volumetric-capture studios: no surface of the set
    is near that colour, so background subtraction finds clean silhouettes even where the objects are
    in shadow; a view culled by the visual hull shows the keyed-out background as its black fill.
    One key light from above the cameras' side; the three objects cast soft shadows (8 shadow rays,
    0.06 rad); ambient 0.38, diffuse 0.72. The objects keep :func:`default_scene`'s places (the
    small ball's centre raised onto the stage: z 0.23).
    """
    china, flower = sample_photo("china.jpg"), sample_photo("flower.jpg")
    grain = cv2.cvtColor(china, cv2.COLOR_BGR2GRAY).astype(np.float32) / 255.0
    grain = cv2.resize(grain, (256, 171), interpolation=cv2.INTER_AREA)
    grain = (grain - grain.min()) / max(float(np.ptp(grain)), 1e-6)
    return Scene((
        Plane(material=Material(Noise((26.0, 84.0, 30.0), (38.0, 108.0, 42.0), scale=0.6, octaves=4, seed=3)),
              foreground=False),
        Box((0.0, 0.05, 0.04), (1.8, 1.6, 0.08), Material(Planks(grain, width=0.13, length=1.0)), casts_shadow=False),
        Box((0.0, 0.0, 0.3), (0.5, 0.5, 0.6),
            Material(BoxPicture(_fitted(flower, 256), (0.25, 0.25, 0.3), top=_fitted(flower[:, 107:534], 128))),
            yaw_deg=20.0),
        Sphere((0.0, 0.0, 0.85), 0.25, Material(SpherePicture(_fitted(china, 384)), specular=0.2, shininess=30.0)),
        Sphere((0.38, -0.32, 0.23), 0.15, Material(SpherePicture(_fitted(flower, 256)), specular=0.15)),
    ), light_dir=(-0.45, -0.6, 0.8), ambient=0.38, diffuse=0.72, sky=(36.0, 104.0, 40.0), shadows=8,
        light_spread=0.06)
