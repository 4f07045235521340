"""The ``reconstruction`` job: a drone video (or a zip of ordered stills) -> cameras and points.

Inputs: ``media`` (a video or a zip of images), optionally ``calibration`` (a calibration file,
see :func:`workers.drone.calibration.parse_calibration`). Parameters:
:class:`~workers.drone.params.ReconstructionParams`. Results: ``points.ply``, ``cameras.txt``,
``images.txt``, ``points3D.txt`` (a COLMAP text model), ``trajectory.json``, ``report.json``,
``preview.png``; with ``dense`` also ``dense.ply`` (points, normals, colours) and ``depth.zip``
(16-bit depth PNGs, their scales in ``report.json`` under ``dense``), see :mod:`workers.drone.dense`.
"""
from __future__ import annotations

import json
import time
from typing import Any

from pydantic import ValidationError

from workers.common.jobctx import JobContext, JobInputError
from workers.common.validation import describe_errors
from workers.registry import JobKind

from .calibration import Intrinsics, from_values, parse_calibration
from .dense import DenseResult, dense_ply_bytes, densify, depth_zip, reference_frames
from .export import colmap_text, ply_bytes, trajectory_json
from .frames import load_frames
from .params import ReconstructionParams, max_dense_volume_from_env
from .preview import preview_png
from .reconstruction import ProgressFn, SparseModel, reconstruct

__all__ = ["ReconstructionParams", "dense_pass", "run_reconstruction", "resolve_intrinsics", "write_outputs"]

RESULT_NAMES = ("points.ply", "cameras.txt", "images.txt", "points3D.txt", "trajectory.json", "report.json",
                "preview.png")
DENSE_RESULT_NAMES = ("dense.ply", "depth.zip")
SPARSE_SHARE = 0.6  # with a dense pass, the sparse stages report progress up to this fraction


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


def dense_pass(model: SparseModel, media, intrinsics: Intrinsics, params: ReconstructionParams,
               progress: ProgressFn | None = None, media_name: str | None = None) -> DenseResult:
    """Decode the reference frames of ``media`` again (``intrinsics`` at its native resolution, as given to
    :func:`reconstruct`) and run :func:`workers.drone.dense.densify` on them (progress 0..1 as it reports).
    Raises JobInputError when the sparse model has fewer than two registered frames
    or an 'sgm' dense pass would hold more than ``$SWEEPCAST_MAX_DENSE_VOLUME`` cost-volume cells."""
    p = params
    if p.dense_aggregation == "sgm":
        cells = int(round(model.width * p.dense_scale)) * int(round(model.height * p.dense_scale)) * p.dense_planes
        limit = max_dense_volume_from_env()
        if cells > limit:
            raise JobInputError(f"dense_aggregation 'sgm' would hold {cells:,} cost-volume cells (depth-map pixels x "
                                f"planes); the limit is {limit:,}: lower dense_scale or dense_planes, or use 'window'")
    refs = reference_frames(model.registered, p.dense_frames)
    if len(refs) < 2:
        raise JobInputError(f"a dense reconstruction needs two registered frames; {len(refs)} registered")
    if progress is not None:
        progress(0.0, "dense frames")
    frames = load_frames(media, intrinsics, model.frame_index[refs], p.max_width, media_name)
    images = {int(f): frames[int(model.frame_index[f])] for f in refs if int(model.frame_index[f]) in frames}
    try:
        return densify(model, images, p, progress)
    except ValueError as exc:
        raise JobInputError(f"dense reconstruction: {exc}") from None


def write_outputs(model: SparseModel, write, dense: DenseResult | None = None) -> dict[str, float]:
    """Write every result through ``write(name, bytes)`` (with ``dense``: also dense.ply and depth.zip,
    and the preview gains the dense view); returns seconds per output."""
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    write("points.ply", ply_bytes(model.points, model.colors))
    for name, text in colmap_text(model).items():
        write(name, text.encode())
    write("trajectory.json", trajectory_json(model))
    if dense is not None:
        write("dense.ply", dense_ply_bytes(dense.cloud))
        write("depth.zip", depth_zip(dense.names, dense.pngs))
    times["export"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    reg = model.registered
    write("preview.png", preview_png(model.points, model.colors, model.R[reg], model.t[reg],
                                     dense=(dense.cloud.points, dense.cloud.colors) if dense is not None else None))
    times["preview"] = time.perf_counter() - t0
    return times


def run_reconstruction(ctx: JobContext) -> dict[str, Any]:
    """Job entry point (see the module docstring); returns a short summary."""
    try:
        params = ReconstructionParams.model_validate(ctx.params)
    except ValidationError as exc:
        raise JobInputError(f"invalid parameters: {describe_errors(exc)}") from None
    if "media" not in ctx.inputs:
        raise JobInputError("missing input 'media' (a video or a zip of ordered images)")
    calib = ctx.read_input("calibration") if "calibration" in ctx.inputs else None
    intrinsics = resolve_intrinsics(params, calib)
    ctx.progress(0.0, "decode")
    # Messages name the file the user sent, not its storage key (or an object store's cache file).
    media_name = ctx.input_meta.get("media", {}).get("filename") or "the media"
    share = SPARSE_SHARE if params.dense else 1.0
    model = reconstruct(ctx.input_path("media"), intrinsics, params, lambda f, s: ctx.progress(f * share, s),
                        media_name)
    dense = None
    if params.dense:
        span = 0.97 - SPARSE_SHARE
        t0 = time.perf_counter()
        dense = dense_pass(model, ctx.input_path("media"), intrinsics, params,
                           lambda f, s: ctx.progress(SPARSE_SHARE + span * f, s), media_name)
        model.report["timings_s"]["dense"] = round(time.perf_counter() - t0, 4)
        model.report["dense"] = dense.report
    ctx.progress(0.98, "export")
    model.report["timings_s"].update(
        {k: round(v, 4) for k, v in write_outputs(model, ctx.write_result, dense).items()})
    ctx.write_result("report.json", json.dumps(model.report, indent=1).encode())
    ctx.progress(1.0, "done")
    rep = model.report
    out = {
        "frames_registered": rep["frames"]["registered"],
        "frames_selected": rep["frames"]["selected"],
        "points": rep["points"],
        "reprojection_error_px": rep["reprojection_error_px"]["after_ba"]["mean"],
        "results": list(RESULT_NAMES) + (list(DENSE_RESULT_NAMES) if dense is not None else []),
    }
    if dense is not None:
        out["dense_points"] = dense.report["points"]
    return out


RECONSTRUCT_JOB = JobKind("drone.reconstruct", run_reconstruction, ReconstructionParams)
JOBS = (RECONSTRUCT_JOB,)
