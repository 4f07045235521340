"""Upsampling a decoded low-resolution depth map to the texture size, as a 3D-video decoder does.

Both kernels are pixel-centre aligned (OpenCV's ``INTER_NEAREST_EXACT`` and ``INTER_LINEAR``), so
an integer factor ``n`` with nearest neighbour replicates each sample into an n x n block.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from .errors import DepthInputError, OutputTooLarge

UPSAMPLERS = {"nearest": cv2.INTER_NEAREST_EXACT, "bilinear": cv2.INTER_LINEAR}
MAX_SIDE = 32768


def target_size(
    shape_hw: tuple[int, int], scale: float | None = None, size: tuple[int, int] | None = None,
    max_pixels: int | None = None,
) -> tuple[int, int]:
    """The output (width, height) from either a scale factor or an explicit size.

    shape_hw: (H, W) of the input. scale: factor > 0 (output side = round(side * scale)).
    size: (width, height) in pixels. Exactly one of them may be given; neither means factor 1.
    Raises DepthInputError for a factor <= 0, a non-finite one, a size that is not positive, or
    an output over ``max_pixels`` (width x height; None: no limit but MAX_SIDE per side), with code
    ``output_too_large``: checked here, before any output array is allocated.
    """
    h, w = shape_hw
    if scale is not None and size is not None:
        raise DepthInputError("give either a scale factor or a target size, not both")
    if size is not None:
        tw, th = (int(v) for v in size)
        if tw != size[0] or th != size[1] or tw <= 0 or th <= 0:
            raise DepthInputError(f"target size must be two positive integers (width, height), got {size}")
    else:
        s = 1.0 if scale is None else float(scale)
        if not math.isfinite(s) or s <= 0:
            raise DepthInputError(f"scale factor must be a positive number, got {scale}")
        tw, th = max(1, int(round(w * s))), max(1, int(round(h * s)))
    if tw > MAX_SIDE or th > MAX_SIDE:
        raise OutputTooLarge(f"target size {tw}x{th} exceeds the {MAX_SIDE}-pixel limit per side")
    if max_pixels is not None and tw * th > max_pixels:
        raise OutputTooLarge(f"the output would be {tw}x{th} = {tw * th:,} pixels; the limit is {max_pixels:,} "
                             f"pixels (ask for a smaller scale or out_width/out_height)")
    return tw, th


def upsample(
    depth: np.ndarray, scale: float | None = None, size: tuple[int, int] | None = None,
    mode: str = "nearest",
) -> np.ndarray:
    """Resize depth levels (H, W) uint8/uint16 to the target size; same dtype.

    mode: "nearest" or "bilinear" (DepthInputError otherwise). ``scale``/``size`` as in
    :func:`target_size`; the input is returned unchanged when the size already matches.
    """
    if mode not in UPSAMPLERS:
        raise DepthInputError(f"unknown upsampler {mode!r}; expected one of {', '.join(UPSAMPLERS)}")
    tw, th = target_size(depth.shape[:2], scale, size)
    if (th, tw) == depth.shape[:2]:
        return depth
    return cv2.resize(depth, (tw, th), interpolation=UPSAMPLERS[mode])
