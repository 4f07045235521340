"""Job entry point: post-filter a depth sequence frame by frame.

``run_depth_video(ctx)``: input ``depth``, raw planar YUV (:class:`DepthVideoParams` says its
layout) or, with ``input_format: "video"``, a coded 8-bit H.264/HEVC video whose luma is the depth
(decoded with PyAV; at most ``SWEEPCAST_MAX_VIDEO_FRAMES`` frames and ``SWEEPCAST_MAX_IMAGE_PIXELS``
pixels per frame, the service's settings); optional input ``texture`` (8-bit 4:2:0 YUV at the output
size, needed by the guided methods). Results: ``filtered.yuv`` (the output size, ``bits`` deep, in
the ``chroma`` format) and ``report.json``. Progress is reported once per frame.
"""
from __future__ import annotations

import json
import time
from contextlib import ExitStack
from typing import Any, Iterator

import cv2
import numpy as np
from pydantic import ValidationError

from workers.common.jobctx import JobContext, JobInputError
from workers.common.validation import describe_errors
from workers.registry import JobKind

from . import io
from .errors import CorruptVideo, DepthInputError
from .levels import levels_to_depth
from .methods import GUIDED_METHODS
from .params import DepthVideoParams
from .pipeline import FramePipeline
from .upsample import target_size
from .video import DepthVideoInfo, decode_depth_video, probe_depth_video

def run_depth_video(ctx: JobContext) -> dict[str, Any]:
    """Filter every frame of the ``depth`` sequence; returns a short summary (also in report.json)."""
    try:
        p = DepthVideoParams.model_validate(ctx.params)
    except ValidationError as exc:
        raise JobInputError(f"invalid parameters: {describe_errors(exc)}") from None
    depth_path = ctx.input_path("depth")
    max_frames, max_pixels = ctx.settings.max_video_frames, ctx.settings.max_image_pixels
    if p.input_format == "video":
        info = check_video_input(probe_depth_video(depth_path, max_frames, max_pixels), p)
        width, height, count = info.width, info.height, info.frames
        described = {"format": "video", "codec": info.codec, "pix_fmt": info.pix_fmt}
        frames_in = decode_depth_video(depth_path, max_frames, max_pixels)
    else:
        width, height = p.width, p.height
        described = {"format": "yuv", "chroma": p.chroma}
        fmt_in = io.YuvFormat(width, height, p.bits, p.chroma)
        name = ctx.input_meta.get("depth", {}).get("filename") or "the sequence"
        count = io.yuv_sequence_frames(depth_path.stat().st_size, fmt_in, max_frames, name)
        frames_in = None
    out_w, out_h = target_size((height, width), p.scale, p.out_size(), max_pixels)
    fmt_out = io.YuvFormat(out_w, out_h, p.bits, p.chroma)
    method = p.method_for("texture" in ctx.inputs)
    pipeline = FramePipeline((height, width), (out_w, out_h), method, p.upsampler, p.options(p.bits))
    frames: list[dict[str, float]] = []
    started = time.perf_counter()
    with ExitStack() as stack:
        if frames_in is None:
            frames_in = io.read_yuv_frames(stack.enter_context(depth_path.open("rb")), fmt_in, count)
        fout = stack.enter_context(ctx.result_path("filtered.yuv").open("wb"))
        guides = _guides(ctx, stack, method, out_w, out_h, count)
        for index, frame in enumerate(frames_in):
            if index >= count:
                raise CorruptVideo(f"the video decodes to more frames than its {count} packets")
            out = pipeline(frame, next(guides))
            io.write_yuv_frame(fout, out, fmt_out)
            frames.append(_frame_stats(pipeline.upsampled, out, p))
            ctx.progress((index + 1) / count, f"frame {index + 1}/{count}")
    count = len(frames)
    seconds = time.perf_counter() - started
    summary = {
        "frames": count,
        "input": {"width": width, "height": height, "bits": p.bits, **described},
        "output": {"width": out_w, "height": out_h, "bits": p.bits, "chroma": p.chroma},
        "method": method,
        "seconds": round(seconds, 3),
        "frames_per_second": round(count / seconds, 2) if seconds > 0 else None,
    }
    report = {**summary, "params": p.model_dump(mode="json"), "per_frame": frames}
    ctx.write_result("report.json", json.dumps(report, indent=2).encode())
    return summary


def check_video_input(info: DepthVideoInfo, p: DepthVideoParams) -> DepthVideoInfo:
    """``info`` when the video agrees with the parameters (width/height, when given); DepthInputError otherwise."""
    for name, given, found in (("width", p.width, info.width), ("height", p.height, info.height)):
        if given is not None and given != found:
            raise DepthInputError(f"the depth video is {info.width}x{info.height} but the parameters say "
                                  f"{name} {given}: leave width/height out for video input, or match them")
    return info


def _guides(
    ctx: JobContext, stack: ExitStack, method: str, width: int, height: int, count: int
) -> Iterator[np.ndarray | None]:
    """Texture frames for guided methods (validated against the depth sequence), else Nones."""
    if method not in GUIDED_METHODS:
        while True:
            yield None
    if "texture" not in ctx.inputs:
        raise JobInputError(f"method {method!r} needs a 'texture' input: 8-bit 4:2:0 YUV at {width}x{height}")
    path = ctx.input_path("texture")
    tex_frames = path.stat().st_size / (width * height * 3 // 2)
    if width % 2 or height % 2 or tex_frames != count:
        raise JobInputError(
            f"texture must hold {count} frames of 8-bit 4:2:0 YUV at {width}x{height} "
            f"({count * width * height * 3 // 2} bytes), got {path.stat().st_size} bytes"
        )
    yield from io.read_texture_yuv_frames(stack.enter_context(path.open("rb")), width, height, count)


def _frame_stats(up: np.ndarray, out: np.ndarray, p: DepthVideoParams) -> dict[str, float]:
    """How much the filter changed the upsampled frame; the depth range in metres when known."""
    diff = cv2.absdiff(out, up)
    lo, hi, _, _ = cv2.minMaxLoc(out)
    stats = {
        "changed_fraction": round(cv2.countNonZero(diff) / diff.size, 6),
        "mean_abs_change_levels": round(float(cv2.mean(diff)[0]), 4),
        "min_level": int(lo),
        "max_level": int(hi),
    }
    if p.z_near is not None:
        z = levels_to_depth(np.array([stats["max_level"], stats["min_level"]]), p.z_near, p.z_far, p.bits,
                            p.larger_is_nearer)
        stats["nearest_m"], stats["farthest_m"] = sorted(round(float(v), 4) for v in z)
    return stats


VIDEO_JOB = JobKind("depth.video", run_depth_video, DepthVideoParams)
JOBS = (VIDEO_JOB,)
