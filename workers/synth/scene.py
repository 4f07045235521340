"""Scene primitives (sphere, box, plane) and their analytic ray intersections.

World frame: any right-handed frame; the helpers in :mod:`workers.synth.rigs` use z up, metres.
Rays are ``X = origin + t * D`` with ``D`` (N, 3); when ``D``'s camera-z component is 1 (as the
renderer builds them), ``t`` is the depth along the optical axis.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import _kernels
from .textures import Color, Solid, Texture


@dataclass(frozen=True)
class Material:
    """Lambertian texture plus an optional Phong highlight (view-dependent).

    ``specular`` in 0..1 scales a white highlight of exponent ``shininess``.
    """

    texture: Texture = field(default_factory=Solid)
    specular: float = 0.0
    shininess: float = 40.0


@dataclass(frozen=True)
class Sphere:
    """A sphere: ``center`` (3,) m, ``radius`` m. ``foreground`` objects form the silhouette;
    ``casts_shadow``: whether it shadows others in a scene with shadows."""

    center: tuple[float, float, float]
    radius: float
    material: Material = field(default_factory=Material)
    foreground: bool = True
    casts_shadow: bool = True

    def intersect_into(self, o: np.ndarray, D: np.ndarray, k: int, best_t: np.ndarray, ids: np.ndarray,
                       normals: np.ndarray) -> None:
        """Z-buffer update for rays ``o + t D`` (see :mod:`workers.synth._kernels`)."""
        _kernels.sphere_hits(o, D, np.asarray(self.center, np.float64), float(self.radius), k, best_t, ids, normals)

    def local(self, X: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> texture coordinates (N, 3)."""
        return X - np.asarray(self.center, np.float64)

    def blocks_into(self, O: np.ndarray, d: np.ndarray, blocked: np.ndarray) -> None:
        """Set ``blocked`` (N,) uint8 to 1 where the ray from O (N, 3) along d (3,) unit meets the sphere."""
        _kernels.sphere_blocks(O, d, np.asarray(self.center, np.float64), float(self.radius), blocked)


@dataclass(frozen=True)
class Box:
    """An oriented box: ``center`` (3,), full edge lengths ``size`` (3,), turned by ``yaw_deg`` about z;
    ``casts_shadow`` as for :class:`Sphere`."""

    center: tuple[float, float, float]
    size: tuple[float, float, float]
    material: Material = field(default_factory=Material)
    foreground: bool = True
    yaw_deg: float = 0.0
    casts_shadow: bool = True

    @property
    def rotation(self) -> np.ndarray:
        """World-to-box rotation (3, 3)."""
        a = np.radians(self.yaw_deg)
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])

    def intersect_into(self, o: np.ndarray, D: np.ndarray, k: int, best_t: np.ndarray, ids: np.ndarray,
                       normals: np.ndarray) -> None:
        """Z-buffer update for rays ``o + t D`` (slab method; see :mod:`workers.synth._kernels`)."""
        h = np.asarray(self.size, np.float64) / 2
        _kernels.box_hits(o, D, self.rotation, np.asarray(self.center, np.float64), h, k, best_t, ids, normals)

    def local(self, X: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> box-frame texture coordinates (N, 3) (texture turns with the box)."""
        return (X - np.asarray(self.center, np.float64)) @ self.rotation.T

    def blocks_into(self, O: np.ndarray, d: np.ndarray, blocked: np.ndarray) -> None:
        """Set ``blocked`` (N,) uint8 to 1 where the ray from O (N, 3) along d (3,) unit meets the box."""
        h = np.asarray(self.size, np.float64) / 2
        _kernels.box_blocks(O, d, self.rotation, np.asarray(self.center, np.float64), h, blocked)


@dataclass(frozen=True)
class Plane:
    """An infinite plane through ``point`` with normal ``normal`` (default: the ground z = 0)."""

    point: tuple[float, float, float] = (0.0, 0.0, 0.0)
    normal: tuple[float, float, float] = (0.0, 0.0, 1.0)
    material: Material = field(default_factory=Material)
    foreground: bool = False

    def intersect_into(self, o: np.ndarray, D: np.ndarray, k: int, best_t: np.ndarray, ids: np.ndarray,
                       normals: np.ndarray) -> None:
        """Z-buffer update for rays ``o + t D`` (see :mod:`workers.synth._kernels`)."""
        n = np.asarray(self.normal, np.float64)
        _kernels.plane_hits(o, D, np.asarray(self.point, np.float64), n / np.linalg.norm(n), k, best_t, ids, normals)

    def local(self, X: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> texture coordinates (world frame)."""
        return X


Primitive = Sphere | Box | Plane


@dataclass(frozen=True)
class Scene:
    """Primitives, one directional light and a sky colour (BGR, 0..255) where rays hit nothing.

    ``light_dir`` points from the scene towards the light; shading is
    ``texture * (ambient + diffuse * |n . l|)`` plus the materials' highlights. With ``shadows`` > 0 the
    light is a disc of angular radius ``light_spread`` (radians) sampled by that many shadow rays per
    point, spheres and boxes cast (soft) shadows (unless ``casts_shadow=False``), and the diffuse term is one-sided:
    ``diffuse * max(n . l, 0) * (share of the shadow rays that reach the light)`` (planes cast none).
    """

    objects: tuple[Primitive, ...]
    light_dir: tuple[float, float, float] = (0.4, -0.3, 0.85)
    ambient: float = 0.45
    diffuse: float = 0.55
    sky: Color = (235.0, 206.0, 135.0)
    shadows: int = 0
    light_spread: float = 0.05

    def background_only(self) -> "Scene":
        """The same scene without its foreground objects (what an empty studio shows)."""
        return Scene(tuple(o for o in self.objects if not o.foreground), self.light_dir,
                     self.ambient, self.diffuse, self.sky, self.shadows, self.light_spread)

    def shadow_directions(self) -> np.ndarray:
        """The unit directions (shadows, 3) towards points of the light's disc (a sunflower spiral)."""
        light = np.asarray(self.light_dir, np.float64)
        light /= np.linalg.norm(light)
        a = np.cross(light, [1.0, 0.0, 0.0] if abs(light[0]) < 0.9 else [0.0, 1.0, 0.0])
        a /= np.linalg.norm(a)
        b = np.cross(light, a)
        k = np.arange(self.shadows)
        rad = self.light_spread * np.sqrt((k + 0.5) / max(self.shadows, 1))
        ang = k * np.pi * (3 - np.sqrt(5))
        dirs = light + rad[:, None] * (np.cos(ang)[:, None] * a + np.sin(ang)[:, None] * b)
        return dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
