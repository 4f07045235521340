"""The depth engine over encoded images (PNG/PGM in, PNG out): what the synchronous routes and the CLI call.

User-caused problems raise an :class:`~workers.common.errors.InputError` (:class:`DepthInputError`, the decoder's
image errors, :class:`~workers.camera.CameraError`): the service answers its status.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from workers.common import images
from workers.common.work import WorkEstimate

from . import dibr, io
from .cost import filter_estimate, synthesis_estimate
from .errors import DepthInputError, OutputTooLarge
from .levels import levels_to_depth, levels_to_disparity
from .methods import postprocess
from .params import DepthFilterParams, SynthesizeParams
from .upsample import target_size


def filter_depth_bytes(
    depth: bytes, params: DepthFilterParams | dict[str, Any], texture: bytes | None = None,
    max_pixels: int | None = None,
) -> bytes:
    """Upsample and post-filter one depth map.

    depth: PNG/PGM bytes (8- or 16-bit grey levels). texture: image bytes at the output size, needed
    by guided methods ("wmf", "jbu", "wmf_dilation"; method "auto" picks one when it is given); its size also sets the output size when no scale/size is given.
    max_pixels: the largest input image and output (width x height); None: the process's limit
    (:func:`workers.common.images.max_pixels_from_env`). Each is refused with an InputError before
    it is decoded or allocated. Returns the filtered depth as PNG bytes with the input's bit depth.
    """
    p = params if isinstance(params, DepthFilterParams) else DepthFilterParams.model_validate(params)
    limit = max_pixels if max_pixels is not None else images.max_pixels_from_env()
    levels, bits = io.decode_depth(depth, p.bits, limit)
    size = p.out_size()
    if p.scale is not None or size is not None:  # else the guide's size, checked when it is decoded
        size = target_size(levels.shape, p.scale, size, limit)
    guide = io.decode_texture(texture, limit) if texture is not None else None
    out = postprocess(levels, p.method_for(guide is not None), size=size, upsampler=p.upsampler, guide=guide, options=p.options(bits))
    return io.encode_depth(out, "png")


def filter_work(
    depth: bytes, params: DepthFilterParams, texture: bytes | None = None, max_pixels: int | None = None,
) -> tuple[WorkEstimate, str] | None:
    """What :func:`filter_depth_bytes` would cost on these inputs, read from the image headers alone (no pixel
    decoded): (estimate, "<method> on a WxH output"). None when the engine refuses the inputs at its own first
    checks (an unreadable header, an image or output over ``max_pixels``, a bad size), which cost no more than
    one checked decode."""
    limit = max_pixels if max_pixels is not None else images.max_pixels_from_env()
    try:
        d = images.read_image_size(depth)
        images.check_pixels(d.width, d.height, limit)
        out = params.out_size()
        if params.scale is not None or out is not None:
            out = target_size((d.height, d.width), params.scale, out, limit)
        if texture is not None:
            t = images.read_image_size(texture)
            images.check_pixels(t.width, t.height, limit)
            out = out or (t.width, t.height)
    except (images.ImageInputError, DepthInputError):
        return None
    w, h = out or (d.width, d.height)
    method = params.method_for(texture is not None)
    return filter_estimate(w * h, method, params.options(8)), f"{method} on a {w}x{h} output"


def synthesis_work(
    views: Sequence[tuple[bytes, bytes]], params: SynthesizeParams, max_pixels: int | None = None,
) -> tuple[WorkEstimate, str] | None:
    """What :func:`synthesize_bytes` would cost on these views, read from the texture headers alone: (estimate,
    "synthesis of a WxH view from N view(s)"). None when the engine refuses the inputs at its own first checks."""
    limit = max_pixels if max_pixels is not None else images.max_pixels_from_env()
    try:
        _check_target_size(params, limit)
        sizes = [images.read_image_size(texture) for texture, _ in views]
        for size in sizes:
            images.check_pixels(size.width, size.height, limit)
    except (images.ImageInputError, DepthInputError):
        return None
    if not sizes or len(views) != params.view_count:
        return None
    cam = params.target_camera  # general geometry: a side it does not give is the first view's
    w = (cam.width if cam is not None else None) or sizes[0].width
    h = (cam.height if cam is not None else None) or sizes[0].height
    estimate = synthesis_estimate([s.pixels for s in sizes], w * h, params.geometry)
    return estimate, f"synthesis of a {w}x{h} view from {len(views)} view(s)"


def synthesize_bytes(
    views: Sequence[tuple[bytes, bytes]], params: SynthesizeParams | dict[str, Any], max_pixels: int | None = None
) -> tuple[bytes, bytes]:
    """Synthesise a virtual view from texture + depth of one or more views.

    views: (texture image bytes, depth PNG/PGM bytes) per source view, in the order of
    ``positions``/``cameras``. max_pixels: the largest image (width x height) decoded and the
    largest target view; None: the process's limit. Returns (synthesised view PNG (BGR 8-bit),
    hole mask PNG: 8-bit, 255 where no source view saw the pixel, before hole filling).
    """
    p = params if isinstance(params, SynthesizeParams) else SynthesizeParams.model_validate(params)
    if len(views) != p.view_count:
        raise DepthInputError(
            f"got {len(views)} views but the parameters describe {p.view_count} camera(s): they must match"
        )
    limit = max_pixels if max_pixels is not None else images.max_pixels_from_env()
    _check_target_size(p, limit)
    textures, depths = [], []
    for i, (tex_bytes, depth_bytes) in enumerate(views):
        tex = io.decode_texture(tex_bytes, limit)
        levels, bits = io.decode_depth(depth_bytes, p.bits, limit)
        dibr.check_texture_depth(tex, levels, f"depth map of view {i}")
        textures.append(tex)
        depths.append((levels, bits))
    result = synthesize_levels(textures, depths, p)
    return images.encode_png(result.image), images.encode_png(result.holes.astype(np.uint8) * 255)


def _check_target_size(p: SynthesizeParams, max_pixels: int) -> None:
    """Refuse a general-geometry target camera over ``max_pixels`` (width x height) before anything is
    decoded; a target without a size (and every rectified one) has the source views' size, which
    their decoding checks."""
    cam = p.target_camera
    if cam is not None and cam.width is not None and cam.height is not None and cam.width * cam.height > max_pixels:
        raise OutputTooLarge(f"the target view would be {cam.width}x{cam.height} = {cam.width * cam.height:,} "
                             f"pixels; the limit is {max_pixels:,} pixels")


def synthesize_levels(
    textures: Sequence[np.ndarray], depths: Sequence[tuple[np.ndarray, int]], p: SynthesizeParams
) -> dibr.Synthesis:
    """Synthesis from decoded views: textures (H, W, 3) uint8, depths (levels (H, W), bits)."""
    kw = dict(hole_fill=p.hole_fill, depth_tolerance=p.depth_tolerance, boundary_width=p.boundary_width)
    if p.geometry == "rectified":
        disparities = [_reference_disparity(levels, bits, p) for levels, bits in depths]
        shifts = [p.target_position - x for x in p.positions]
        return dibr.synthesize_rectified(textures, disparities, shifts, **kw)
    h, w = depths[0][0].shape
    cams = [c.camera(f"view {i}", *textures[i].shape[1::-1]) for i, c in enumerate(p.cameras)]  # CameraError: 422
    target = p.target_camera.camera("target", w, h)
    metres = [
        levels_to_depth(levels, p.z_near, p.z_far, bits, p.larger_is_nearer) for levels, bits in depths
    ]
    return dibr.synthesize_general(textures, metres, cams, target, **kw)


def _reference_disparity(levels: np.ndarray, bits: int, p: SynthesizeParams) -> np.ndarray:
    """Disparity (H, W) float32 for one unit of ``positions``: pixels per metre of baseline for
    inverse depth (f / Z), or level / disparity_scale (NaN where the level is 0) for disparity."""
    if p.depth_units == "disparity":
        d = levels.astype(np.float32) / np.float32(p.disparity_scale)
        return np.where(levels > 0, d, np.nan).astype(np.float32)
    return levels_to_disparity(levels, p.z_near, p.z_far, p.focal_px, bits, p.larger_is_nearer)
