"""What one synchronous depth request will cost, estimated from its sizes and parameters before any pixel is decoded.

The service refuses a request whose estimate is over its limits and admits the others within a shared memory
budget (``app/sync_work.py``). The figures are per megapixel of output and were measured on the reference machine
(2-core AMD EPYC, the whole request: decoding, the method, PNG encoding) on Middlebury Art scaled to 4 MP
(realistic piecewise-smooth depth; ``python -m benchmarks.robustness --only sync_work`` checks them against measured requests):

- CPU seconds grow with the taps each output pixel reads: the weighted mode filter's guide_window² window plus its
  2 * ceil(3 * sigma_depth) + 1 range smoothing, joint bilateral upsampling's (2 * jbu_radius + 1)² samples, the
  Otsu rule's per-window sort (about window³); the OpenCV morphology of the dilation family costs the same at any
  window.
- Peak memory is the arrays a method holds at once: the guided methods widen the depth and the texture to int32
  (about 27 bytes per output pixel), synthesis keeps float32 warps per view (rectified: ~42 + 34 per view,
  general: ~166 + 29 per view bytes per pixel).

A depth map with many levels in each window (noise) makes the weighted mode filter slower than estimated: 1.05
instead of 0.58 CPU-s per MP on random levels, so such a request within the CPU limit may take up to about twice it.
"""
from __future__ import annotations

import math

from workers.common.work import WorkEstimate

from .methods import FilterOptions

MP = 1_000_000


# Seconds per output megapixel (the reference machine) and bytes per output pixel, by method.
_DILATION_FAMILY_S_PER_MP = 0.015
_WMF_S_PER_MP = (0.053, 0.0048, 0.0055)  # constant, per window tap, per range-smoothing tap
_JBU_S_PER_MP = (0.091, 0.0069)  # constant, per low-resolution sample
_OTSU_S_PER_MP_PER_WINDOW3 = 0.0016
_BYTES_PER_PX = {"none": 2, "dilation": 3, "modified": 7, "modified_morph": 7, "wmf": 28, "jbu": 27,
                 "wmf_dilation": 28}
_RECTIFIED = ((0.15, 0.15), (42, 34))  # (s/MP constant, per view), (bytes/px constant, per view)
_GENERAL = ((0.16, 0.24), (166, 29))


def filter_estimate(out_pixels: int, method: str, options: FilterOptions) -> WorkEstimate:
    """The cost of post-filtering one depth map to ``out_pixels`` (width x height of the output) with ``method``
    (an engine method name, "auto" already resolved) and ``options``."""
    mp = out_pixels / MP
    if method in ("wmf", "wmf_dilation"):
        const, per_tap, per_range_tap = _WMF_S_PER_MP
        range_taps = 2 * math.ceil(3 * options.sigma_depth) + 1
        rate = const + per_tap * options.guide_window ** 2 + per_range_tap * range_taps + _DILATION_FAMILY_S_PER_MP
    elif method == "jbu":
        const, per_sample = _JBU_S_PER_MP
        rate = const + per_sample * (2 * options.jbu_radius + 1) ** 2
    elif method in ("modified", "modified_morph") and options.rule == "otsu":
        rate = _DILATION_FAMILY_S_PER_MP + _OTSU_S_PER_MP_PER_WINDOW3 * options.window ** 3
    else:
        rate = _DILATION_FAMILY_S_PER_MP
    return WorkEstimate(rate * mp, int(_BYTES_PER_PX.get(method, max(_BYTES_PER_PX.values())) * out_pixels))


def synthesis_estimate(view_pixels: list[int], target_pixels: int, geometry: str) -> WorkEstimate:
    """The cost of synthesising a ``target_pixels`` view from source views of ``view_pixels`` each (width x height)
    in ``geometry`` "rectified" or "general"."""
    (s_const, s_view), (b_const, b_view) = _RECTIFIED if geometry == "rectified" else _GENERAL
    seconds = s_const * target_pixels / MP + s_view * sum(view_pixels) / MP
    return WorkEstimate(seconds, int(b_const * target_pixels + b_view * sum(view_pixels)))
