"""Weighted mode filtering (Min, Lu & Do, IEEE TIP 2012; reference [9] of the paper).

For each pixel p, a histogram over depth levels is built from the pixels q of a window, each
weighted by a spatial Gaussian ``G_s(|p - q|)`` and a colour Gaussian ``G_c(|I_p - I_q|)`` on the
texture guide I, and spread over neighbouring levels by ``G_r(d - D_q)``. The output is the level
with the largest weight (the mode), so an edge keeps one of the two depths the texture supports
instead of a blend of them, and it follows the texture edge rather than the blocky upsampled one.

16-bit maps are binned 256 levels per bin for the mode search; the output is the weighted mean of
the samples that fell in the winning bin (exactly the bin's level for 8-bit maps).

Defaults (window 9, sigma_color 40, sigma_depth 4) were chosen on Teddy, x2 downsampling, JPEG 70,
by view-synthesis PSNR; Art was held out (``benchmarks/depth.py``).
"""
from __future__ import annotations

import cv2
import numba
import numpy as np

from .errors import DepthInputError


def check_guide(guide: np.ndarray | None, shape_hw: tuple[int, int]) -> np.ndarray:
    """The guide as (H, W, 3) uint8, validated against the depth's (H, W); DepthInputError otherwise."""
    if guide is None:
        raise DepthInputError("this method needs a texture image (the guide) of the same size as the depth map")
    guide = np.asarray(guide)
    if guide.dtype != np.uint8:
        raise DepthInputError(f"texture must be 8-bit, got {guide.dtype}")
    if guide.ndim == 2:
        guide = cv2.cvtColor(guide, cv2.COLOR_GRAY2BGR)
    if guide.ndim != 3 or guide.shape[2] != 3:
        raise DepthInputError(f"texture must be (H, W) grey or (H, W, 3) colour, got shape {guide.shape}")
    if guide.shape[:2] != tuple(shape_hw):
        raise DepthInputError(
            f"texture is {guide.shape[1]}x{guide.shape[0]} but the depth map is {shape_hw[1]}x{shape_hw[0]}: "
            "they must be the same size"
        )
    return guide


def weighted_mode_filter(
    depth: np.ndarray, guide: np.ndarray, window: int = 9, sigma_spatial: float | None = None,
    sigma_color: float = 40.0, sigma_depth: float = 4.0,
) -> np.ndarray:
    """Weighted mode filter of depth levels guided by the texture.

    depth: (H, W) uint8/uint16 levels (already upsampled to the texture size). guide: (H, W, 3)
    uint8 BGR or (H, W) grey texture. window: odd side of the square support (pixels).
    sigma_spatial: pixels (default window / 3); sigma_color: guide grey levels (Euclidean over BGR);
    sigma_depth: levels of the 8-bit scale (bins). Returns (H, W), depth's dtype.
    """
    if window < 1 or window % 2 == 0 or window > 31:
        raise DepthInputError(f"guide window must be an odd integer from 1 to 31, got {window!r}")
    for name, value in (("sigma_color", sigma_color), ("sigma_depth", sigma_depth)):
        if not value > 0:
            raise DepthInputError(f"{name} must be > 0, got {value}")
    guide = check_guide(guide, depth.shape)
    radius = window // 2
    s_sp = float(sigma_spatial) if sigma_spatial else max(window / 3.0, 0.5)
    yy, xx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    spatial = np.exp(-(xx**2 + yy**2) / (2 * s_sp**2)).astype(np.float32)
    color_lut = np.exp(-np.arange(3 * 255**2 + 1) / (2 * sigma_color**2)).astype(np.float32)
    shift = 0 if depth.dtype == np.uint8 else 8
    spread = int(np.ceil(3 * sigma_depth))
    range_k = np.exp(-np.arange(-spread, spread + 1) ** 2 / (2 * sigma_depth**2)).astype(np.float32)
    out = _wmf(depth.astype(np.int32), guide.astype(np.int32), spatial, color_lut, range_k, shift)
    return out.astype(depth.dtype)


@numba.njit(parallel=True, cache=True)
def _wmf(depth, guide, spatial, color_lut, range_k, shift):
    h, w = depth.shape
    radius = spatial.shape[0] // 2
    spread = range_k.shape[0] // 2
    nbins = (65535 >> shift) + 1
    out = np.empty((h, w), np.int32)
    for y in numba.prange(h):
        # padded by ``spread`` on both sides so the smoothing below never leaves the array
        weight = np.zeros(nbins + 2 * spread, np.float32)
        value = np.zeros(nbins + 2 * spread, np.float32)
        for x in range(w):
            b0, g0, r0 = guide[y, x, 0], guide[y, x, 1], guide[y, x, 2]
            lo, hi = nbins, -1
            for dy in range(-radius, radius + 1):
                yy = y + dy
                if yy < 0 or yy >= h:
                    continue
                for dx in range(-radius, radius + 1):
                    xx = x + dx
                    if xx < 0 or xx >= w:
                        continue
                    db = guide[yy, xx, 0] - b0
                    dg = guide[yy, xx, 1] - g0
                    dr = guide[yy, xx, 2] - r0
                    wt = spatial[dy + radius, dx + radius] * color_lut[db * db + dg * dg + dr * dr]
                    v = depth[yy, xx]
                    b = (v >> shift) + spread
                    weight[b] += wt
                    value[b] += wt * v
                    lo = min(lo, b)
                    hi = max(hi, b)
            # the mode of the G_r-smoothed histogram lies between the extreme samples
            best, best_b = -1.0, lo
            for b in range(lo, hi + 1):
                acc = 0.0
                for k in range(-spread, spread + 1):
                    acc += weight[b + k] * range_k[k + spread]
                if acc > best:
                    best, best_b = acc, b
            if weight[best_b] > 0:
                out[y, x] = int(value[best_b] / weight[best_b] + 0.5)
            else:
                out[y, x] = (best_b - spread) << shift
            weight[lo:hi + 1] = 0.0
            value[lo:hi + 1] = 0.0
    return out


def joint_bilateral_upsample(
    depth_low: np.ndarray, guide: np.ndarray, radius: int = 2, sigma_spatial: float = 1.0,
    sigma_color: float = 12.0,
) -> np.ndarray:
    """Joint bilateral upsampling (Kopf, Cohen, Lischinski & Uyttendaele, SIGGRAPH 2007; reference
    [7] of the paper) of a low-resolution depth map to the guide's size.

    Output pixel p = sum_q D_low(q) f(|p_low - q|) g(|I_p - I_q|) / sum_q f g, over the low-resolution
    samples q within ``radius`` (low-resolution pixels) of p's position p_low in the low-resolution
    grid (pixel-centre aligned); f, g: Gaussians of ``sigma_spatial`` (low-resolution pixels) and
    ``sigma_color`` (grey levels, Euclidean over BGR); I_q is the guide averaged over the area sample q covers (the
guide resized to the low resolution with ``INTER_AREA``, as the depth itself was downsampled).

    depth_low: (h, w) uint8/uint16 levels. guide: (H, W, 3) uint8 BGR or (H, W) grey at the output
    size. Returns (H, W) levels of depth_low's dtype (rounded weighted mean). A factor of 1 (same
    size) makes it a joint bilateral filter.
    """
    if not isinstance(radius, (int, np.integer)) or not 1 <= radius <= 15:
        raise DepthInputError(f"jbu radius must be an integer from 1 to 15, got {radius!r}")
    for name, value in (("sigma_spatial", sigma_spatial), ("sigma_color", sigma_color)):
        if not value > 0:
            raise DepthInputError(f"{name} must be > 0, got {value}")
    if depth_low.ndim != 2 or depth_low.dtype not in (np.uint8, np.uint16):
        raise DepthInputError(f"depth map must be (H, W) uint8/uint16, got {depth_low.dtype} {depth_low.shape}")
    guide = np.asarray(guide)
    if guide.ndim < 2:
        raise DepthInputError(f"texture must be an image, got shape {guide.shape}")
    guide = check_guide(guide, guide.shape[:2])
    h, w = guide.shape[:2]
    color_lut = np.exp(-np.arange(3 * 255**2 + 1) / (2 * sigma_color**2)).astype(np.float32)
    low_guide = cv2.resize(guide, (depth_low.shape[1], depth_low.shape[0]), interpolation=cv2.INTER_AREA)
    out = _jbu(depth_low.astype(np.float32), guide.astype(np.int32), low_guide.astype(np.int32), int(radius),
               float(sigma_spatial), color_lut)
    top = 255 if depth_low.dtype == np.uint8 else 65535
    return np.clip(np.rint(out), 0, top).astype(depth_low.dtype)


@numba.njit(parallel=True, cache=True)
def _jbu(depth_low, guide, low_guide, radius, sigma_spatial, color_lut):
    h, w = guide.shape[:2]
    lh, lw = depth_low.shape
    sy, sx = lh / h, lw / w  # low-resolution pixels per output pixel
    inv2s2 = 1.0 / (2.0 * sigma_spatial * sigma_spatial)
    out = np.empty((h, w), np.float32)
    for y in numba.prange(h):
        yl = (y + 0.5) * sy - 0.5
        cy = int(np.floor(yl + 0.5))
        for x in range(w):
            xl = (x + 0.5) * sx - 0.5
            cx = int(np.floor(xl + 0.5))
            b0, g0, r0 = guide[y, x, 0], guide[y, x, 1], guide[y, x, 2]
            acc, norm = 0.0, 0.0
            for qy in range(max(0, cy - radius), min(lh, cy + radius + 1)):
                for qx in range(max(0, cx - radius), min(lw, cx + radius + 1)):
                    db = low_guide[qy, qx, 0] - b0
                    dg = low_guide[qy, qx, 1] - g0
                    dr = low_guide[qy, qx, 2] - r0
                    d2 = (qy - yl) ** 2 + (qx - xl) ** 2
                    wt = np.exp(-d2 * inv2s2) * color_lut[db * db + dg * dg + dr * dr]
                    acc += wt * depth_low[qy, qx]
                    norm += wt
            if norm > 1e-12:
                out[y, x] = acc / norm
            else:  # no sample carries weight: nearest sample
                out[y, x] = depth_low[min(lh - 1, max(0, cy)), min(lw - 1, max(0, cx))]
    return out
