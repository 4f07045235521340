"""The ``reconstruction`` job: a drone video (or a zip of ordered stills) -> cameras and points, and for
a georeferenced flight an orthophoto, a surface model and a LAZ cloud.

Inputs: ``media`` (a video or a zip of images), optionally ``calibration`` (a calibration file, see
:func:`workers.drone.calibration.parse_calibration`) and ``telemetry`` (a DJI ``.SRT`` file for a video).
Parameters: :class:`~workers.drone.params.ReconstructionParams`. Results (see
:mod:`workers.drone.pipeline`): ``points.ply``, ``cameras.txt``, ``images.txt``, ``points3D.txt`` (a COLMAP
text model), ``trajectory.json``, ``report.json``, ``preview.png``; with ``dense`` also ``dense.ply`` and
``depth.zip`` (16-bit depth PNGs, their scales in ``report.json`` under ``dense``); georeferenced also
``points.laz``; with map products ``orthophoto.tif``/``orthophoto.png`` and ``dsm.tif``/``dsm.png``.
"""
from __future__ import annotations

from typing import Any

from pydantic import ValidationError

from workers.common.jobctx import JobContext, JobInputError
from workers.common.validation import describe_errors
from workers.registry import JobKind

from .params import ReconstructionParams
from .pipeline import reconstruct_and_write, summary

__all__ = ["ReconstructionParams", "run_reconstruction"]


def run_reconstruction(ctx: JobContext) -> dict[str, Any]:
    """Job entry point (see the module docstring); returns a short summary."""
    try:  # the runtime's model is returned as it is; a dict (tests, the CLI's contexts) is checked here
        params = ReconstructionParams.model_validate(ctx.params)
    except ValidationError as exc:
        raise JobInputError(f"invalid parameters: {describe_errors(exc)}") from None
    if "media" not in ctx.inputs:
        raise JobInputError("missing input 'media' (a video or a zip of ordered images)")
    calib = ctx.read_input("calibration") if "calibration" in ctx.inputs else None
    telemetry = ctx.read_input("telemetry") if "telemetry" in ctx.inputs else None
    # Messages name the file the user sent, not its storage key (or an object store's cache file).
    media_name = ctx.input_meta.get("media", {}).get("filename") or "the media"
    # The stages' tasks run across the cluster (in the service) and keep their data in the job's work area, so that
    # another attempt goes on from what this one finished.
    return summary(reconstruct_and_write(ctx.input_path("media"), params, calib, telemetry, ctx.progress,
                                         ctx.result_path, media_name, ctx.fanout(), ctx.work_area(),
                                         ctx.input_ref("media")))


RECONSTRUCT_JOB = JobKind("drone.reconstruct", run_reconstruction, ReconstructionParams)
JOBS = (RECONSTRUCT_JOB,)
