"""Job entry point: post-filter a raw YUV depth sequence frame by frame.

``run_depth_video(ctx)``: input ``depth`` (raw planar YUV, :class:`DepthVideoParams` says its
layout), optional input ``texture`` (8-bit 4:2:0 YUV at the output size, needed by "wmf").
Results: ``filtered.yuv`` (the output size, same bit depth and chroma format) and ``report.json``.
Progress is reported once per frame.
"""
from __future__ import annotations

import json
import time
from contextlib import ExitStack
from typing import Any, Iterator

import cv2
import numpy as np
from pydantic import ValidationError

from workers.common import images
from workers.common.jobctx import JobContext, JobInputError

from . import io
from .levels import levels_to_depth
from .methods import GUIDED_METHODS
from .params import DepthVideoParams
from .pipeline import FramePipeline
from .upsample import target_size


def run_depth_video(ctx: JobContext) -> dict[str, Any]:
    """Filter every frame of the ``depth`` sequence; returns a short summary (also in report.json)."""
    try:
        p = DepthVideoParams.model_validate(ctx.params)
    except ValidationError as exc:
        raise JobInputError(f"invalid parameters: {exc}") from None
    fmt_in = io.YuvFormat(p.width, p.height, p.bits, p.chroma)
    depth_path = ctx.input_path("depth")
    count = io.yuv_frame_count(depth_path.stat().st_size, fmt_in)
    out_w, out_h = target_size((p.height, p.width), p.scale, p.out_size(), images.max_pixels_from_env())
    fmt_out = io.YuvFormat(out_w, out_h, p.bits, p.chroma)
    pipeline = FramePipeline((p.height, p.width), (out_w, out_h), p.method, p.upsampler, p.options(p.bits))
    frames: list[dict[str, float]] = []
    started = time.perf_counter()
    with ExitStack() as stack:
        fin = stack.enter_context(depth_path.open("rb"))
        fout = stack.enter_context(ctx.result_path("filtered.yuv").open("wb"))
        guides = _guides(ctx, stack, p, out_w, out_h, count)
        for index, frame in enumerate(io.read_yuv_frames(fin, fmt_in, count)):
            out = pipeline(frame, next(guides))
            io.write_yuv_frame(fout, out, fmt_out)
            frames.append(_frame_stats(pipeline.upsampled, out, p))
            ctx.progress((index + 1) / count, f"frame {index + 1}/{count}")
    seconds = time.perf_counter() - started
    summary = {
        "frames": count,
        "input": {"width": p.width, "height": p.height, "bits": p.bits, "chroma": p.chroma},
        "output": {"width": out_w, "height": out_h, "bits": p.bits, "chroma": p.chroma},
        "method": p.method,
        "seconds": round(seconds, 3),
        "frames_per_second": round(count / seconds, 2) if seconds > 0 else None,
    }
    report = {**summary, "params": p.model_dump(mode="json"), "per_frame": frames}
    ctx.write_result("report.json", json.dumps(report, indent=2).encode())
    return summary


def _guides(
    ctx: JobContext, stack: ExitStack, p: DepthVideoParams, width: int, height: int, count: int
) -> Iterator[np.ndarray | None]:
    """Texture frames for guided methods (validated against the depth sequence), else Nones."""
    if p.method not in GUIDED_METHODS:
        while True:
            yield None
    if "texture" not in ctx.inputs:
        raise JobInputError(f"method {p.method!r} needs a 'texture' input: 8-bit 4:2:0 YUV at {width}x{height}")
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
