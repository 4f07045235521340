"""The post-processing methods behind one interface, and the decoder-side pipeline.

Every method is ``fn(depth, guide, options) -> depth``: depth (H, W) uint8/uint16 levels at the
texture size, guide (H, W, 3) uint8 BGR texture or None, options a :class:`FilterOptions`. Methods
work with larger = nearer; :func:`apply_method` flips maps in the opposite convention around them.

``METHODS`` names: "none", "dilation" (eq. 1), "modified" (modified dilation), "modified_morph"
(modified dilation + morphological filter), "wmf" (weighted mode filter, guided by the texture),
"jbu" (joint bilateral upsampling guided by the texture: in :func:`postprocess` it replaces the
plain upsampler and reads the decoded low-resolution map itself; on a map already at the texture
size it is the joint bilateral filter), "wmf_dilation" (the weighted mode filter, then dilation
with ``window``: the edge moves onto the texture edge, then the foreground grows by window // 2
pixels to carry the mixed-colour boundary pixels with it; the best of the methods by BD-rate of
synthesised views in ``benchmarks/depth.py``).

:data:`RECOMMENDED` / :func:`recommended_method`: the method to use when a request does not name
one ("wmf_dilation" when a texture is at hand, else "dilation", the measured order).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from . import edge_aware, filters
from .errors import DepthInputError
from .levels import check_levels, flip
from .upsample import target_size, upsample


@dataclass(frozen=True)
class FilterOptions:
    """Parameters of all methods; each method reads the ones it uses.

    window: side of N(k) for the dilation family (odd pixels). rule / min_contrast: the
    foreground classification (see ``filters``). morph_window / morph_order: the clean-up.
    guide_window, sigma_color, sigma_depth: the weighted mode filter (pixels, grey levels, levels).
    jbu_radius, jbu_sigma_spatial, jbu_sigma_color: joint bilateral upsampling (low-resolution
    pixels, low-resolution pixels, grey levels).
    bits: bit depth of the levels (8..16). larger_is_nearer: the level convention.
    """

    window: int = 3
    rule: str = "midrange"
    min_contrast: int = 0
    morph_window: int = 3
    morph_order: str = "close"
    guide_window: int = 9
    sigma_color: float = 40.0
    sigma_depth: float = 4.0
    jbu_radius: int = 2
    jbu_sigma_spatial: float = 1.0
    jbu_sigma_color: float = 12.0
    bits: int = 8
    larger_is_nearer: bool = True


MethodFn = Callable[[np.ndarray, "np.ndarray | None", FilterOptions], np.ndarray]


def _none(depth: np.ndarray, guide: np.ndarray | None, o: FilterOptions) -> np.ndarray:
    return depth


def _dilation(depth: np.ndarray, guide: np.ndarray | None, o: FilterOptions) -> np.ndarray:
    return filters.dilation(depth, o.window)


def _modified(depth: np.ndarray, guide: np.ndarray | None, o: FilterOptions) -> np.ndarray:
    return filters.modified_dilation(depth, o.window, o.rule, o.min_contrast)


def _modified_morph(depth: np.ndarray, guide: np.ndarray | None, o: FilterOptions) -> np.ndarray:
    return filters.modified_dilation_morph(
        depth, o.window, o.rule, o.min_contrast, o.morph_window, o.morph_order
    )


def _wmf(depth: np.ndarray, guide: np.ndarray | None, o: FilterOptions) -> np.ndarray:
    return edge_aware.weighted_mode_filter(
        depth, guide, o.guide_window, sigma_color=o.sigma_color, sigma_depth=o.sigma_depth
    )


def _jbu(depth: np.ndarray, guide: np.ndarray | None, o: FilterOptions) -> np.ndarray:
    return edge_aware.joint_bilateral_upsample(
        depth, guide, o.jbu_radius, sigma_spatial=o.jbu_sigma_spatial, sigma_color=o.jbu_sigma_color
    )


def _wmf_dilation(depth: np.ndarray, guide: np.ndarray | None, o: FilterOptions) -> np.ndarray:
    return filters.dilation(_wmf(depth, guide, o), o.window)


METHODS: dict[str, MethodFn] = {
    "none": _none,
    "dilation": _dilation,
    "modified": _modified,
    "modified_morph": _modified_morph,
    "wmf": _wmf,
    "jbu": _jbu,
    "wmf_dilation": _wmf_dilation,
}
GUIDED_METHODS = frozenset({"wmf", "jbu", "wmf_dilation"})
UPSAMPLING_METHODS = frozenset({"jbu"})
"""Methods that upsample the decoded map themselves (the upsampler setting does not apply)."""


RECOMMENDED = {"guided": "wmf_dilation", "unguided": "dilation"}
"""Best measured method with and without a texture guide (benchmarks/RESULTS.md, section depth)."""


def recommended_method(has_guide: bool) -> str:
    """The method a request that names none gets: "wmf_dilation" with a texture, else "dilation"."""
    return RECOMMENDED["guided" if has_guide else "unguided"]


def check_method(name: str) -> str:
    """``name`` if it is a known method; DepthInputError listing the known ones otherwise."""
    if name not in METHODS:
        raise DepthInputError(f"unknown method {name!r}; expected one of {', '.join(METHODS)}")
    return name


def apply_method(
    depth: np.ndarray, method: str, guide: np.ndarray | None = None, options: FilterOptions = FilterOptions()
) -> np.ndarray:
    """Run one method on depth levels (H, W) uint8/uint16 at the texture size; same shape and dtype.

    guide: (H, W, 3) uint8 texture, required by the guided methods (DepthInputError otherwise);
    when given it must match the depth's size.
    """
    fn = METHODS[check_method(method)]
    check_levels(depth, options.bits)
    if guide is not None or method in GUIDED_METHODS:
        guide = edge_aware.check_guide(guide, depth.shape)
    if options.larger_is_nearer:
        return fn(depth, guide, options)
    return flip(fn(flip(depth, options.bits), guide, options), options.bits)


def postprocess(
    depth_low: np.ndarray, method: str, *, scale: float | None = None, size: tuple[int, int] | None = None,
    upsampler: str = "nearest", guide: np.ndarray | None = None, options: FilterOptions = FilterOptions(),
) -> np.ndarray:
    """The decoder side: upsample a decoded depth map, then post-filter it.

    depth_low: (h, w) uint8/uint16 levels. scale or size (width, height): the output size; when
    both are None and a guide is given, the guide's size. Returns (H, W) levels, same dtype.
    Methods in :data:`UPSAMPLING_METHODS` ("jbu") take ``depth_low`` directly and ignore ``upsampler``.
    """
    check_method(method)
    check_levels(depth_low, options.bits)
    if scale is None and size is None and guide is not None:
        size = (guide.shape[1], guide.shape[0])
    if method in UPSAMPLING_METHODS:
        return upsample_guided(depth_low, method, target_size(depth_low.shape, scale, size), guide, options)
    return apply_method(upsample(depth_low, scale, size, upsampler), method, guide, options)


def upsample_guided(
    depth_low: np.ndarray, method: str, size: tuple[int, int], guide: np.ndarray | None, options: FilterOptions,
) -> np.ndarray:
    """An upsampling method (``jbu``) from the decoded (h, w) levels straight to ``size`` (width,
    height), the guide's size; honours the level convention like :func:`apply_method`."""
    guide = edge_aware.check_guide(guide, (size[1], size[0]))
    fn = METHODS[method]
    if options.larger_is_nearer:
        return fn(depth_low, guide, options)
    return flip(fn(flip(depth_low, options.bits), guide, options), options.bits)
