"""Request parameters of the depth engine (validated by the web layer and again by the jobs).

- :class:`DepthFilterParams`: one depth map -> filtered depth map (``POST /v1/depth/filter``).
- :class:`DepthVideoParams`: a depth sequence (raw YUV, or H.264/HEVC video) -> filtered sequence
  (job ``depth.video``).
- :class:`SynthesizeParams`: texture + depth of one or more views -> a virtual view (``POST /v1/depth/synthesize``).
"""
from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from workers.camera import Camera

from .methods import FilterOptions, recommended_method

# Unknown fields are typos; NaN and Infinity (which JSON parsers accept) are no sizes or positions.
STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)
MethodName = Literal["auto", "none", "dilation", "modified", "modified_morph", "wmf", "jbu", "wmf_dilation"]


def _odd(value: int) -> int:
    if value % 2 == 0:
        raise ValueError(f"must be odd, got {value}")
    return value


class _FilterFields(BaseModel):
    """The method, its parameters and the output size (shared by the filter requests)."""

    model_config = STRICT

    method: MethodName = Field("auto", description=(
        "post-filter; 'auto': the best measured one the inputs allow, 'wmf_dilation' with a texture, "
        "else 'dilation' (benchmarks/RESULTS.md, section depth)"))
    window: int = Field(3, ge=1, le=31, description="side of the neighbourhood N(k), odd pixels")
    rule: Literal["midrange", "otsu"] = Field("midrange", description="foreground/background classification")
    min_contrast: int = Field(0, ge=0, le=65535, description="levels; flatter windows have no foreground")
    morph_window: int = Field(3, ge=1, le=31, description="structuring element of the clean-up, odd pixels")
    morph_order: Literal["close", "open", "close-open", "open-close"] = "close"
    guide_window: int = Field(9, ge=1, le=31, description="weighted mode filter support, odd pixels")
    sigma_color: float = Field(40.0, gt=0, le=1000, description="weighted mode filter colour sigma (grey levels)")
    sigma_depth: float = Field(4.0, gt=0, le=64, description="weighted mode filter level sigma (8-bit levels)")
    jbu_radius: int = Field(2, ge=1, le=15, description="joint bilateral upsampling support, low-resolution pixels")
    jbu_sigma_spatial: float = Field(1.0, gt=0, le=15, description="jbu spatial sigma, low-resolution pixels")
    jbu_sigma_color: float = Field(12.0, gt=0, le=1000, description="jbu colour sigma (grey levels)")
    larger_is_nearer: bool = Field(True, description="False for maps where larger levels are farther")
    upsampler: Literal["nearest", "bilinear"] = "nearest"
    scale: float | None = Field(None, gt=0, le=16, description="upsampling factor (or give out_width/out_height)")
    out_width: int | None = Field(None, ge=1, le=32768)
    out_height: int | None = Field(None, ge=1, le=32768)

    _check_odd = field_validator("window", "morph_window", "guide_window")(_odd)

    @model_validator(mode="after")
    def _one_size(self) -> "_FilterFields":
        if (self.out_width is None) != (self.out_height is None):
            raise ValueError("give both out_width and out_height, or neither")
        if self.scale is not None and self.out_width is not None:
            raise ValueError("give either scale or out_width/out_height, not both")
        return self

    def options(self, bits: int) -> FilterOptions:
        """The engine's FilterOptions for maps of ``bits`` bits."""
        return FilterOptions(
            window=self.window, rule=self.rule, min_contrast=self.min_contrast, morph_window=self.morph_window,
            morph_order=self.morph_order, guide_window=self.guide_window, sigma_color=self.sigma_color,
            sigma_depth=self.sigma_depth, jbu_radius=self.jbu_radius, jbu_sigma_spatial=self.jbu_sigma_spatial,
            jbu_sigma_color=self.jbu_sigma_color, bits=bits, larger_is_nearer=self.larger_is_nearer,
        )

    def method_for(self, has_texture: bool) -> str:
        """The engine method to run: ``method``, or for "auto" the recommended one given whether a
        texture came with the request."""
        return recommended_method(has_texture) if self.method == "auto" else self.method

    def out_size(self) -> tuple[int, int] | None:
        """(width, height) when given explicitly."""
        return None if self.out_width is None else (self.out_width, self.out_height)


class DepthFilterParams(_FilterFields):
    """``POST /v1/depth/filter``: inputs ``depth`` (PNG/PGM) and, for "wmf", ``texture`` (image of the output size).

    bits: the map's bit depth (8..16); None takes 8 or 16 from the file, a mismatch is an error.
    """

    bits: int | None = Field(None, ge=8, le=16)


class DepthVideoParams(_FilterFields):
    """Job ``depth.video``: input ``depth`` and, for the guided methods, ``texture`` (8-bit 4:2:0
    YUV at the output size, same frame count). Results ``filtered.yuv`` (raw planar YUV at the output
    size, ``bits`` deep, in the ``chroma`` format) and ``report.json``.

    input_format: "yuv" (raw planar frames: width and height required, bits and chroma say the
    layout) or "video" (a coded H.264/HEVC 8-bit video in any container FFmpeg reads, e.g. raw
    .264/.265, MP4, MKV: its luma plane is the depth; width/height, when given, must match it).
    z_near/z_far (metres, optional): when given, the report states each frame's depth range in metres.
    """

    input_format: Literal["yuv", "video"] = Field("yuv", description="raw planar YUV, or a coded H.264/HEVC video")
    width: int | None = Field(None, ge=1, le=32768, description="input frame width (pixels); required for YUV")
    height: int | None = Field(None, ge=1, le=32768, description="input frame height (pixels); required for YUV")
    bits: int = Field(8, ge=8, le=16)
    chroma: Literal["400", "420"] = "400"
    z_near: float | None = Field(None, gt=0)
    z_far: float | None = Field(None, gt=0)

    @model_validator(mode="after")
    def _planes(self) -> "DepthVideoParams":
        if self.input_format == "yuv" and (self.width is None or self.height is None):
            raise ValueError("raw YUV input needs width and height (pixels)")
        if self.input_format == "video" and self.bits != 8:
            raise ValueError("a coded depth video is 8-bit: leave bits at 8")
        if (self.z_near is None) != (self.z_far is None):
            raise ValueError("give both z_near and z_far, or neither")
        if self.z_near is not None and not self.z_far > self.z_near:
            raise ValueError(f"z_far ({self.z_far}) must be greater than z_near ({self.z_near})")
        return self


class CameraModel(BaseModel):
    """A pinhole camera: K (3x3), world-to-camera R (3x3) and t (3), x_cam = R X + t (metres);
    width/height only for the target (default: the source views' size)."""

    model_config = STRICT

    K: list[list[float]]
    R: list[list[float]] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    t: list[float] = [0.0, 0.0, 0.0]
    width: int | None = Field(None, ge=1, le=32768)
    height: int | None = Field(None, ge=1, le=32768)

    def camera(self, name: str, width: int, height: int) -> Camera:
        """A validated :class:`Camera` (CameraError, a ValueError, when K/R/t are unusable)."""
        return Camera(name, np.array(self.K), np.array(self.R), np.array(self.t),
                      self.width or width, self.height or height)


class SynthesizeParams(BaseModel):
    """``POST /v1/depth/synthesize``: inputs ``texture-0``, ``depth-0`` [, ``texture-1``, ``depth-1``, ...].

    depth_units: "inverse_depth" (MPEG levels; z_near/z_far in metres) or "disparity" (level /
    disparity_scale = disparity in pixels for the reference baseline; level 0 = unknown).
    geometry "rectified": cameras on a horizontal line; ``positions`` are the source cameras' x
    (metres for inverse depth, reference baselines for disparity) and ``target_position`` the
    virtual camera's; inverse depth also needs ``focal_px``. geometry "general": ``cameras`` and
    ``target_camera`` (inverse depth only).
    """

    model_config = STRICT

    geometry: Literal["rectified", "general"] = "rectified"
    depth_units: Literal["inverse_depth", "disparity"] = "inverse_depth"
    bits: int | None = Field(None, ge=8, le=16)
    larger_is_nearer: bool = True
    z_near: float | None = Field(None, gt=0)
    z_far: float | None = Field(None, gt=0)
    disparity_scale: float = Field(1.0, gt=0)
    focal_px: float | None = Field(None, gt=0)
    positions: list[float] | None = Field(None, min_length=1, max_length=8)
    target_position: float | None = None
    cameras: list[CameraModel] | None = Field(None, min_length=1, max_length=8)
    target_camera: CameraModel | None = None
    hole_fill: Literal["background", "inpaint", "none"] = "background"
    boundary_width: int = Field(1, ge=0, le=16)
    depth_tolerance: float = Field(0.05, gt=0, le=1)

    @model_validator(mode="after")
    def _consistent(self) -> "SynthesizeParams":
        if self.depth_units == "inverse_depth":
            if self.z_near is None or self.z_far is None:
                raise ValueError("inverse-depth levels need z_near and z_far (metres)")
            if not self.z_far > self.z_near:
                raise ValueError(f"z_far ({self.z_far}) must be greater than z_near ({self.z_near})")
        if self.geometry == "rectified":
            if self.positions is None or self.target_position is None:
                raise ValueError("rectified geometry needs positions (one per view) and target_position")
            if self.depth_units == "inverse_depth" and self.focal_px is None:
                raise ValueError("rectified geometry with inverse-depth levels needs focal_px")
        else:
            if self.depth_units != "inverse_depth":
                raise ValueError("general geometry needs inverse-depth levels (z_near/z_far), not disparity")
            if self.cameras is None or self.target_camera is None:
                raise ValueError("general geometry needs cameras (one per view) and target_camera")
        return self

    @property
    def view_count(self) -> int:
        """How many source views the parameters describe."""
        return len(self.positions if self.geometry == "rectified" else self.cameras)
