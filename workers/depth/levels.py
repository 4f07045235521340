"""Depth levels of 3D video: 8- to 16-bit inverse depth, larger = nearer (MPEG convention).

A level ``v`` in ``[0, 2^bits - 1]`` encodes ``1/Z`` linearly between ``1/Z_far`` (v = 0) and
``1/Z_near`` (v = max)::

    1/Z = v / max * (1/Z_near - 1/Z_far) + 1/Z_far

With ``larger_is_nearer=False`` the level axis is reversed (v = 0 is nearest). Disparity between two
rectified cameras (focal ``f`` pixels, baseline ``B`` metres) is ``f B / Z``: linear in the level.
"""
from __future__ import annotations

import math

import numpy as np

from .errors import DepthInputError

MIN_BITS = 8
MAX_BITS = 16


def check_bits(bits: int) -> int:
    """``bits`` as an int in [8, 16]; raises DepthInputError otherwise."""
    if not isinstance(bits, (int, np.integer)) or not MIN_BITS <= int(bits) <= MAX_BITS:
        raise DepthInputError(f"bit depth must be an integer from {MIN_BITS} to {MAX_BITS}, got {bits!r}")
    return int(bits)


def max_level(bits: int) -> int:
    """The largest level of a ``bits``-bit depth map (255 for 8 bits)."""
    return (1 << check_bits(bits)) - 1


def level_dtype(bits: int) -> type[np.unsignedinteger]:
    """``np.uint8`` for 8 bits, ``np.uint16`` for 9..16 bits."""
    return np.uint8 if check_bits(bits) == 8 else np.uint16


def check_levels(depth: np.ndarray, bits: int, name: str = "depth") -> np.ndarray:
    """Validate a depth-level map: 2-D, dtype matching ``bits``, values <= 2^bits - 1.

    depth: (H, W) uint8 (bits = 8) or uint16 (bits 9..16). Returns it unchanged; raises
    DepthInputError naming what was expected.
    """
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise DepthInputError(f"{name} must be a single-channel (H, W) map, got shape {depth.shape}")
    if depth.size == 0:
        raise DepthInputError(f"{name} is empty")
    dtype = level_dtype(bits)
    if depth.dtype != dtype:
        raise DepthInputError(
            f"{name} has {depth.dtype.itemsize * 8}-bit samples ({depth.dtype}) but bit depth {bits} "
            f"expects {np.dtype(dtype).name}"
        )
    if bits not in (8, 16) and int(depth.max()) > max_level(bits):
        raise DepthInputError(f"{name} has level {int(depth.max())} above the {bits}-bit maximum {max_level(bits)}")
    return depth


def check_planes(z_near: float, z_far: float) -> None:
    """Raise DepthInputError unless 0 < z_near < z_far (z_far may be infinite)."""
    if not (math.isfinite(z_near) and z_near > 0 and z_far > z_near):
        raise DepthInputError(f"need 0 < z_near < z_far, got z_near={z_near}, z_far={z_far}")


def flip(levels: np.ndarray, bits: int) -> np.ndarray:
    """Reverse the level axis (``max - v``): converts between the two conventions. Same dtype."""
    return (max_level(bits) - levels.astype(np.int64)).astype(levels.dtype)


def levels_to_inverse_depth(
    levels: np.ndarray, z_near: float, z_far: float, bits: int = 8, larger_is_nearer: bool = True
) -> np.ndarray:
    """Levels (H, W) uint -> inverse depth ``1/Z`` in 1/metres, float64 (H, W)."""
    check_planes(z_near, z_far)
    v = np.asarray(levels, np.float64) / max_level(bits)
    if not larger_is_nearer:
        v = 1.0 - v
    inv_far = 0.0 if math.isinf(z_far) else 1.0 / z_far
    return v * (1.0 / z_near - inv_far) + inv_far


def levels_to_depth(
    levels: np.ndarray, z_near: float, z_far: float, bits: int = 8, larger_is_nearer: bool = True
) -> np.ndarray:
    """Levels (H, W) uint -> depth Z in metres, float32 (H, W); infinite where 1/Z = 0."""
    inv = levels_to_inverse_depth(levels, z_near, z_far, bits, larger_is_nearer)
    with np.errstate(divide="ignore"):
        return (1.0 / inv).astype(np.float32)


def depth_to_levels(
    depth_m: np.ndarray, z_near: float, z_far: float, bits: int = 8, larger_is_nearer: bool = True
) -> np.ndarray:
    """Depth Z in metres (H, W) float -> levels (H, W) uint8/uint16, rounded; Z clipped to [z_near, z_far]."""
    check_planes(z_near, z_far)
    z = np.clip(np.asarray(depth_m, np.float64), z_near, z_far)
    inv_far = 0.0 if math.isinf(z_far) else 1.0 / z_far
    v = (1.0 / z - inv_far) / (1.0 / z_near - inv_far)
    if not larger_is_nearer:
        v = 1.0 - v
    return np.rint(v * max_level(bits)).astype(level_dtype(bits))


def levels_to_disparity(
    levels: np.ndarray, z_near: float, z_far: float, focal_baseline: float, bits: int = 8,
    larger_is_nearer: bool = True,
) -> np.ndarray:
    """Levels (H, W) -> disparity ``f B / Z`` in pixels, float32 (H, W).

    focal_baseline: focal length in pixels times baseline in metres (pixel-metres).
    """
    inv = levels_to_inverse_depth(levels, z_near, z_far, bits, larger_is_nearer)
    return (focal_baseline * inv).astype(np.float32)


def disparity_to_levels(
    disparity_px: np.ndarray, z_near: float, z_far: float, focal_baseline: float, bits: int = 8,
    larger_is_nearer: bool = True,
) -> np.ndarray:
    """Disparity in pixels (H, W) -> levels (H, W) uint8/uint16 (inverse of levels_to_disparity)."""
    d = np.asarray(disparity_px, np.float64)
    with np.errstate(divide="ignore"):
        z = np.where(d > 0, focal_baseline / np.maximum(d, 1e-300), np.inf)
    return depth_to_levels(z, z_near, z_far, bits, larger_is_nearer)
