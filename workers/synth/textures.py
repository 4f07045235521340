"""Solid (3D) textures: a colour for every surface point, the same from every viewpoint.

Each texture maps points in the object's local frame, (N, 3) float64 metres, to colours
(N, 3) float32 BGR in 0..255. Colours given to constructors are BGR tuples in 0..255.
Procedural: Solid, Checker, Noise, ColorNoise. From photographs (bilinear, no mip-mapping: give them at
about the resolution they are seen at): Picture (projected along an axis), BoxPicture (a box's faces),
SpherePicture (wrapped in longitude/latitude), Planks (a plank floor whose grain is a photograph's).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

Color = tuple[float, float, float]


@dataclass(frozen=True)
class Solid:
    """One flat colour (BGR, 0..255)."""

    color: Color = (128.0, 128.0, 128.0)

    def sample(self, P: np.ndarray) -> np.ndarray:
        """(N, 3) local points -> (N, 3) float32 BGR."""
        return np.broadcast_to(np.asarray(self.color, np.float32), (len(P), 3)).copy()


@dataclass(frozen=True)
class Checker:
    """A 3D checkerboard of cubes of side ``size`` metres in two colours.

    The lattice is offset by a quarter cell so that faces at multiples of ``size`` (a box side,
    the plane z = 0) do not sit on a cell boundary.
    """

    color_a: Color = (40.0, 40.0, 40.0)
    color_b: Color = (220.0, 220.0, 220.0)
    size: float = 0.1

    def sample(self, P: np.ndarray) -> np.ndarray:
        """(N, 3) local points -> (N, 3) float32 BGR."""
        cells = np.floor(np.asarray(P) / self.size + 0.25).astype(np.int64).sum(axis=1)
        odd = (cells & 1).astype(bool)
        out = np.empty((len(P), 3), np.float32)
        out[:] = self.color_a
        out[odd] = self.color_b
        return out


@dataclass(frozen=True)
class Noise:
    """Fractal value noise blending two colours; ``scale`` is the coarsest feature size (m).

    ``octaves`` halve the feature size each (detail down to ``scale / 2**(octaves-1)``).
    """

    color_a: Color = (30.0, 60.0, 90.0)
    color_b: Color = (200.0, 220.0, 240.0)
    scale: float = 0.05
    octaves: int = 4
    seed: int = 0

    def sample(self, P: np.ndarray) -> np.ndarray:
        """(N, 3) local points -> (N, 3) float32 BGR."""
        n = fractal_noise(P, self.scale, self.octaves, self.seed)[:, None]
        a = np.asarray(self.color_a, np.float32)
        b = np.asarray(self.color_b, np.float32)
        return (a + (b - a) * n).astype(np.float32)


@dataclass(frozen=True)
class ColorNoise:
    """Fractal value noise with an independent pattern per channel: vivid, richly coloured texture.

    Channel values lie in ``mean ± contrast/2`` (0..255).
    """

    scale: float = 0.05
    octaves: int = 4
    seed: int = 0
    mean: float = 128.0
    contrast: float = 200.0

    def sample(self, P: np.ndarray) -> np.ndarray:
        """(N, 3) local points -> (N, 3) float32 BGR."""
        chans = [fractal_noise(P, self.scale, self.octaves, self.seed * 3 + c) for c in range(3)]
        n = np.stack(chans, axis=1)
        return np.clip(self.mean + self.contrast * (n - 0.5), 0, 255).astype(np.float32)


# --- photographs --------------------------------------------------------------------------------
def sample_image(image: np.ndarray, u: np.ndarray, v: np.ndarray, wrap: bool = True) -> np.ndarray:
    """Bilinear samples of ``image`` (H, W, 3) float32 BGR at texture coordinates ``u``, ``v`` (N,)
    (0..1 across the width / down the height; pixel centres at (i + 0.5) / W): (N, 3) float32.
    ``wrap`` repeats the image outside 0..1, else its edge pixels continue."""
    h, w = image.shape[:2]
    x = np.asarray(u, np.float64) * w - 0.5
    y = np.asarray(v, np.float64) * h - 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = (x - x0).astype(np.float32)[:, None]
    fy = (y - y0).astype(np.float32)[:, None]
    x0 = x0.astype(np.int64)
    y0 = y0.astype(np.int64)
    if wrap:
        xa, xb, ya, yb = x0 % w, (x0 + 1) % w, y0 % h, (y0 + 1) % h
    else:
        xa, xb = np.clip(x0, 0, w - 1), np.clip(x0 + 1, 0, w - 1)
        ya, yb = np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1)
    top = image[ya, xa] * (1 - fx) + image[ya, xb] * fx
    bottom = image[yb, xa] * (1 - fx) + image[yb, xb] * fx
    return (top * (1 - fy) + bottom * fy).astype(np.float32)


def _as_picture(image: np.ndarray) -> np.ndarray:
    img = np.ascontiguousarray(image, np.float32)
    if img.ndim != 3 or img.shape[2] != 3 or min(img.shape[:2]) < 2:
        raise ValueError(f"a picture must be (H, W, 3) BGR with H, W >= 2, got shape {img.shape}")
    return img


@dataclass(frozen=True, eq=False)
class Picture:
    """A photograph (H, W, 3) BGR 0..255 projected along a local axis onto a surface: the picture spans
    ``size`` = (width, height) metres centred on the local origin, its width along local axis ``u_axis``
    and its height downwards along -``v_axis`` (so ``v_axis`` is up in the picture); repeated beyond.
    Give the image at about the resolution it is seen at (a far finer one aliases: there is no mip-mapping)."""

    image: np.ndarray
    size: tuple[float, float] = (1.0, 1.0)
    u_axis: int = 0
    v_axis: int = 2

    def __post_init__(self) -> None:
        object.__setattr__(self, "image", _as_picture(self.image))

    def sample(self, P: np.ndarray) -> np.ndarray:
        """(N, 3) local points -> (N, 3) float32 BGR."""
        P = np.asarray(P, np.float64)
        u = P[:, self.u_axis] / self.size[0] + 0.5
        v = 0.5 - P[:, self.v_axis] / self.size[1]
        return sample_image(self.image, u, v)


@dataclass(frozen=True, eq=False)
class BoxPicture:
    """Photographs on the faces of a box of half edge lengths ``half`` (3,) m (a :class:`Box`'s size / 2,
    in its local frame): each side face shows ``image`` upright across its full width and height, the
    four sides each a quarter turn further along it (so neighbouring faces differ and meet), and the
    top face ``top`` (default: the image's centre)."""

    image: np.ndarray
    half: tuple[float, float, float]
    top: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "image", _as_picture(self.image))
        if self.top is not None:
            object.__setattr__(self, "top", _as_picture(self.top))

    def sample(self, P: np.ndarray) -> np.ndarray:
        """(N, 3) local points -> (N, 3) float32 BGR."""
        P = np.asarray(P, np.float64)
        h = np.asarray(self.half, np.float64)
        face = np.argmax(np.abs(P) / h, axis=1)
        out = np.empty((len(P), 3), np.float32)
        side = face < 2
        # around the sides: a perimeter coordinate s in [0, 4) (one unit per face), the picture's width
        # stretched over two faces so that the four faces show it twice, shifted by half
        x, y, z = P[side, 0] / h[0], P[side, 1] / h[1], P[side, 2] / h[2]
        f = face[side]
        s = np.where(f == 0, np.where(x > 0, 1.0 + (y + 1) / 2, 3.0 + (1 - y) / 2),
                     np.where(y > 0, 2.0 + (1 - x) / 2, (x + 1) / 2))
        out[side] = sample_image(self.image, s / 2.0, (1 - z) / 2)
        top = ~side
        img = self.top if self.top is not None else self.image
        out[top] = sample_image(img, (P[top, 0] / h[0] + 1) / 2, (1 - P[top, 1] / h[1]) / 2, wrap=False)
        return out


@dataclass(frozen=True, eq=False)
class SpherePicture:
    """A photograph wrapped round a sphere (local frame at its centre) in longitude and latitude: the
    width once round, the height from the top pole to the bottom one."""

    image: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "image", _as_picture(self.image))

    def sample(self, P: np.ndarray) -> np.ndarray:
        """(N, 3) local points -> (N, 3) float32 BGR."""
        P = np.asarray(P, np.float64)
        r = np.maximum(np.linalg.norm(P, axis=1), 1e-12)
        u = np.arctan2(P[:, 1], P[:, 0]) / (2 * np.pi) + 0.5
        v = np.arccos(np.clip(P[:, 2] / r, -1, 1)) / np.pi
        return sample_image(self.image, u, v)


@dataclass(frozen=True, eq=False)
class Planks:
    """A plank floor in the local x-y plane: planks ``width`` m wide along y and ``length`` m long along
    x, each row shifted by a different share of a length, whose grain is a photograph's brightness
    (``grain``, (H, W) float32 0..1) stretched along the plank, each plank from another strip of it, in
    ``tone`` (BGR) with a ``contrast`` around it; ``seam`` m dark joints."""

    grain: np.ndarray
    tone: Color = (70.0, 115.0, 165.0)
    width: float = 0.14
    length: float = 1.2
    contrast: float = 0.9
    seam: float = 0.004

    def __post_init__(self) -> None:
        g = np.ascontiguousarray(self.grain, np.float32)
        if g.ndim != 2 or min(g.shape) < 2:
            raise ValueError(f"grain must be (H, W) with H, W >= 2, got shape {g.shape}")
        object.__setattr__(self, "grain", np.repeat(g[:, :, None], 3, axis=2))

    def sample(self, P: np.ndarray) -> np.ndarray:
        """(N, 3) local points -> (N, 3) float32 BGR."""
        P = np.asarray(P, np.float64)
        row = np.floor(P[:, 1] / self.width)
        shift = ((row * 0.618034) % 1.0) * self.length
        along = (P[:, 0] + shift) / self.length
        plank = np.floor(along)
        hsh = (row * 7.0 + plank * 13.0) % 23.0  # which strip of the photograph: differs per plank
        u = along - plank
        v = (hsh + (P[:, 1] / self.width - row)) / 23.0
        g = sample_image(self.grain, u, v)[:, 0]
        shade = 1.0 + self.contrast * (g - 0.5)
        shade *= 1.0 + 0.08 * (((hsh * 5.0) % 7.0) / 3.0 - 1.0)  # planks differ a little in tone
        across = np.minimum(P[:, 1] / self.width - row, row + 1 - P[:, 1] / self.width) * self.width
        ends = np.minimum(u, 1 - u) * self.length
        shade = np.where(np.minimum(across, ends) < self.seam / 2, 0.45 * shade, shade)
        return (np.asarray(self.tone, np.float32)[None, :] * shade[:, None].astype(np.float32)).clip(0, 255)


Texture = Solid | Checker | Noise | ColorNoise | Picture | BoxPicture | SpherePicture | Planks


def fractal_noise(P: np.ndarray, scale: float, octaves: int, seed: int) -> np.ndarray:
    """Fractal 3D value noise at points P (N, 3) metres -> (N,) float32, roughly in [0, 1].

    Octave k has feature size ``scale / 2**k`` and amplitude ``1 / 2**k``; deterministic in ``seed``.
    """
    P = np.ascontiguousarray(P, np.float64).reshape(-1, 3)
    return _fractal_noise(P, float(scale), int(octaves), np.uint64(seed & 0xFFFFFFFF))


@njit(cache=True, inline="always")
def _hash3(ix: np.int64, iy: np.int64, iz: np.int64, seed: np.uint64) -> float:
    h = (np.uint64(ix) * np.uint64(0x9E3779B185EBCA87)) ^ (np.uint64(iy) * np.uint64(0xC2B2AE3D27D4EB4F))
    h ^= (np.uint64(iz) * np.uint64(0x165667B19E3779F9)) ^ (seed * np.uint64(0x27D4EB2F165667C5))
    h ^= h >> np.uint64(29)
    h *= np.uint64(0xBF58476D1CE4E5B9)
    h ^= h >> np.uint64(32)
    return float(h & np.uint64(0xFFFFFF)) / float(0xFFFFFF)


@njit(cache=True, parallel=True)
def _fractal_noise(P: np.ndarray, scale: float, octaves: int, seed: np.uint64) -> np.ndarray:
    out = np.empty(P.shape[0], np.float32)
    for i in prange(P.shape[0]):
        total = 0.0
        norm = 0.0
        amp = 1.0
        freq = 1.0 / scale
        for o in range(octaves):
            s = seed + np.uint64(o * 7919)
            x = P[i, 0] * freq
            y = P[i, 1] * freq
            z = P[i, 2] * freq
            x0 = np.floor(x)
            y0 = np.floor(y)
            z0 = np.floor(z)
            fx = x - x0
            fy = y - y0
            fz = z - z0
            # smoothstep fade keeps the value noise free of visible lattice creases
            fx = fx * fx * (3 - 2 * fx)
            fy = fy * fy * (3 - 2 * fy)
            fz = fz * fz * (3 - 2 * fz)
            ix = np.int64(x0)
            iy = np.int64(y0)
            iz = np.int64(z0)
            v = 0.0
            for dz in range(2):
                wz = fz if dz else 1 - fz
                for dy in range(2):
                    wy = fy if dy else 1 - fy
                    for dx in range(2):
                        wx = fx if dx else 1 - fx
                        v += wx * wy * wz * _hash3(ix + dx, iy + dy, iz + dz, s)
            total += amp * v
            norm += amp
            amp *= 0.5
            freq *= 2.0
        out[i] = total / norm
    return out
