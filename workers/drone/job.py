"""The ``reconstruction`` job: a drone video (or a zip of ordered stills) -> cameras and points.

Inputs: ``media`` (a video or a zip of images), optionally ``calibration`` (a calibration file,
see :func:`workers.drone.calibration.parse_calibration`). Parameters:
:class:`~workers.drone.params.ReconstructionParams`. Results: ``points.ply``, ``cameras.txt``,
``images.txt``, ``points3D.txt`` (a COLMAP text model), ``trajectory.json``, ``report.json``,
``preview.png``.
"""
from __future__ import annotations

import json
import time
from typing import Any

from pydantic import ValidationError

from workers.common.jobctx import JobContext, JobInputError

from .calibration import Intrinsics, from_values, parse_calibration
from .export import colmap_text, ply_bytes, trajectory_json
from .params import ReconstructionParams
from .preview import preview_png
from .reconstruction import SparseModel, reconstruct

__all__ = ["ReconstructionParams", "run_reconstruction", "resolve_intrinsics", "write_outputs"]

RESULT_NAMES = ("points.ply", "cameras.txt", "images.txt", "points3D.txt", "trajectory.json", "report.json",
                "preview.png")


def resolve_intrinsics(params: ReconstructionParams, calibration_file: bytes | None = None) -> Intrinsics:
    """Intrinsics from fx/fy/cx/cy, the ``calibration`` text, or an uploaded calibration file
    (in that order); ``params.distortion`` overrides the file's. Raises JobInputError when none."""
    if params.fx is not None:
        intr = from_values(params.fx, params.fy, params.cx, params.cy)
    elif params.calibration is not None:
        intr = parse_calibration(params.calibration)
    elif calibration_file is not None:
        intr = parse_calibration(calibration_file)
    else:
        raise JobInputError("missing intrinsics: give fx, fy, cx, cy (pixels) or a calibration file")
    if params.distortion is not None:
        intr = from_values(intr.fx, intr.fy, intr.cx, intr.cy, params.distortion)
    return intr


def write_outputs(model: SparseModel, write) -> dict[str, float]:
    """Write every result through ``write(name, bytes)``; returns seconds per output."""
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    write("points.ply", ply_bytes(model.points, model.colors))
    for name, text in colmap_text(model).items():
        write(name, text.encode())
    write("trajectory.json", trajectory_json(model))
    times["export"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    reg = model.registered
    write("preview.png", preview_png(model.points, model.colors, model.R[reg], model.t[reg]))
    times["preview"] = time.perf_counter() - t0
    return times


def run_reconstruction(ctx: JobContext) -> dict[str, Any]:
    """Job entry point (see the module docstring); returns a short summary."""
    try:
        params = ReconstructionParams.model_validate(ctx.params)
    except ValidationError as exc:
        raise JobInputError(f"invalid parameters: {exc.errors()[0].get('msg', exc)}") from None
    if "media" not in ctx.inputs:
        raise JobInputError("missing input 'media' (a video or a zip of ordered images)")
    calib = ctx.read_input("calibration") if "calibration" in ctx.inputs else None
    intrinsics = resolve_intrinsics(params, calib)
    ctx.progress(0.0, "decode")
    # Messages name the file the user sent, not its storage key (or an object store's cache file).
    media_name = ctx.input_meta.get("media", {}).get("filename") or "the media"
    model = reconstruct(ctx.input_path("media"), intrinsics, params, ctx.progress, media_name)
    ctx.progress(0.98, "export")
    model.report["timings_s"].update({k: round(v, 4) for k, v in write_outputs(model, ctx.write_result).items()})
    ctx.write_result("report.json", json.dumps(model.report, indent=1).encode())
    ctx.progress(1.0, "done")
    rep = model.report
    return {
        "frames_registered": rep["frames"]["registered"],
        "frames_selected": rep["frames"]["selected"],
        "points": rep["points"],
        "reprojection_error_px": rep["reprojection_error_px"]["after_ba"]["mean"],
        "results": list(RESULT_NAMES),
    }
