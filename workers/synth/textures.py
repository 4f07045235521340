"""Solid (3D) textures: a colour for every surface point, the same from every viewpoint.

Each texture maps points in the object's local frame, (N, 3) float64 metres, to colours
(N, 3) float32 BGR in 0..255. Colours given to constructors are BGR tuples in 0..255.
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


Texture = Solid | Checker | Noise | ColorNoise


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
