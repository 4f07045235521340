"""The batch job: fix the orientation tag of many uploaded photos.

Inputs are named ``photo-0000``, ``photo-0001``, ... with ``input_meta[name]["filename"]`` the
original file name. Results:

- ``report.json``: a list with one entry per photo, in input order:
  ``{"index", "input", "filename", "report": OrientationReport | null, "error": {"code", "message"} | null,
  "fixed_file": "fixed/0003-IMG_1234.jpg" | null, "note": str | null, "review": null}`` (``review``: a person's
  decision, added by the review page's API: :func:`record_review`; the page's thumbnails are made when it asks,
  ``app/routers/review.py``);
- ``fixed/<index>-<sanitised name>.<ext>``: each photo (JPEG, WebP, TIFF, PNG) whose tag was written;
- ``fixed/<index>-<sanitised name>.<ext>.xmp``: the XMP sidecar of each HEIF, AVIF or RAW photo (or of
  every photo with ``sidecar``) whose orientation was written.

A photo that cannot be read is reported in its entry and the others are still processed. The job fans out
(:mod:`workers.orientation.blocks`): blocks of photos run as Ray tasks on every CPU of the cluster, each reading its
photos from the blob store and writing its files there; as each block finishes, the job reports one progress event
per photo of it (``done`` of ``total`` photos, ``eta_s``). An attempt run again after a lost worker or a restart
analyses only the photos whose block no earlier attempt finished. The YuNet model and the pixel limit come from the
worker's environment (``SWEEPCAST_ORIENTATION_YUNET_MODEL``, ``SWEEPCAST_MAX_IMAGE_PIXELS``), never from the request.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from workers.common.jobctx import JobContext, JobInputError
from workers.common.pace import Pace, describe_seconds
from workers.orientation.blocks import (FILES, BlockTask, PhotoRef, analyse_block, files_of, finished_photos,
                                        fixed_name, plan_blocks, sanitize_filename)
from workers.orientation.detect import Method, detector_config, face_detector
from workers.orientation.review import ChoiceWrite, needs_review
from workers.registry import JobKind
from workers.settings import worker_settings

YUNET_MODEL_ENV = "SWEEPCAST_ORIENTATION_YUNET_MODEL"


class OrientationBatchParams(BaseModel):
    """Parameters of an ``orientation.batch`` job."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)  # NaN/Infinity: never a valid value

    force: bool = Field(False, description="replace an existing Orientation tag other than 1")
    write: bool = Field(True, description="write the fixed files (false: reports only)")
    sidecar: bool = Field(False, description="write XMP sidecars for every photo instead of changing any photo")
    method: Method = Field("auto", description="detector: auto (combined when YuNet is configured, else paper), "
                                               "paper, yunet or combined")
    text: bool = Field(True, description="when the faces decide nothing, try the text cue (where the service has it "
                                         "on); false: faces only, which saves 0.1-0.6 s of CPU per photo "
                                         "without a face")


def configured_yunet(models_folder: Path | None) -> Path | None:
    """The YuNet model ``$SWEEPCAST_ORIENTATION_YUNET_MODEL`` names, else the one installed in
    ``models_folder``, else None."""
    return worker_settings().yunet_model(models_folder)


def run_orientation_batch(ctx: JobContext) -> dict[str, Any]:
    """Analyse every ``photo-NNNN`` input in blocks, tag the photos, write ``report.json`` and ``fixed/*``."""
    params = OrientationBatchParams.model_validate(ctx.params)
    names = sorted(ctx.inputs)
    if not names:
        raise JobInputError("the batch has no photos")
    try:
        config = detector_config(ctx.settings, ctx.settings.models_dir, params.method)
        config = config.model_copy(update={"text": config.text and params.text})
        face_detector(config)  # a configuration that cannot work fails the job here, once (the text cue, which
        # never fails a job, is built only where photos are analysed: about a second saved in this process)
    except ValueError as exc:
        raise JobInputError(str(exc)) from None
    photos = [PhotoRef(i, name, str(ctx.input_meta.get(name, {}).get("filename") or name))
              for i, name in enumerate(names)]
    work = ctx.work_area()
    done = finished_photos(work)
    if done:
        ctx.progress(len(done) / len(photos), f"{len(done)} of {len(photos)} photos done by an earlier attempt",
                     done=len(done), total=len(photos))
    todo = [p for p in photos if p.index not in done]
    mode = "sidecar" if params.sidecar else "file"
    fan = ctx.fanout()
    tasks = [BlockTask(work, block, config, params.force, params.write, mode, ctx.settings.max_image_pixels)
             for block in plan_blocks(todo, fan.parallelism)]
    pace = Pace(len(todo))
    for _, record in fan.run(analyse_block, tasks, "photos"):
        pace.add(len(record["entries"]))
        for entry in record["entries"]:
            done[entry["index"]] = (entry, {f: record["files"][f] for f in files_of(entry)})
            _report_progress(ctx, entry, len(done), len(photos), pace.seconds_left())
    for _, files in done.values():
        for name, size in files.items():
            ctx.adopt_result(name, f"{FILES}/{name}", size)
    entries = [done[p.index][0] for p in photos]
    ctx.write_result("report.json", json.dumps(entries, indent=2).encode())
    return summary_of(entries)


def _report_progress(ctx: JobContext, entry: dict[str, Any], done: int, total: int, eta_s: float | None) -> None:
    """One progress event for a photo just analysed: its outcome, the count and the time left."""
    left = "" if eta_s is None or done == total else f"; about {describe_seconds(eta_s)} left"
    stage = f"photo {done}/{total} {entry['filename'][-80:]}: {_outcome(entry)}{left}"
    ctx.progress(done / total, stage, done=done, total=total, eta_s=eta_s)


def record_review(entry: dict[str, Any], rotation: int | None, reviewer: str, at: str,
                  written: ChoiceWrite | None, fixed_file: str | None) -> dict[str, Any]:
    """``entry`` (a report.json entry) with a person's decision: the turn (None: left as it is), who, when, what was
    written where. The engine's own report stays as it was, beside it."""
    review = {"decided_by": "person", "reviewer": reviewer, "at": at, "rotation_degrees": rotation,
              "action": "left_as_is" if written is None else "written",
              "orientation": written.orientation if written else None,
              "target": written.target if written else "none", "fixed_file": fixed_file}
    return {**entry, "review": review, "fixed_file": fixed_file if written else entry.get("fixed_file")}


def _outcome(entry: dict[str, Any]) -> str:
    """The progress line's word for one photo: the decision and its cue, why it needs review, or the error."""
    report = entry["report"]
    if report is None:
        return f"error: {entry['error']['code']}"
    if report["needs_review"]:
        return f"rejected ({report['reject_reason']}), needs review"
    return f"{report['decision']} by {report['cue']}"


def summary_of(entries: list[dict[str, Any]]) -> dict[str, Any]:
    """The job's summary over its entries: the engine's decisions, and how many need a person and were reviewed."""
    decisions = [e["report"]["decision"] for e in entries if e["report"]]
    cues = [e["report"]["cue"] for e in entries if e["report"]]
    return {
        "photos": len(entries),
        "upright": decisions.count("upright"),
        "rotated": decisions.count("rotated"),
        "rejected": decisions.count("rejected"),
        "not_analysed": decisions.count("not_analysed"),
        "decided_by_faces": cues.count("faces"),
        "decided_by_text": cues.count("text"),
        "errors": sum(e["error"] is not None for e in entries),
        "written": sum(e["fixed_file"] is not None for e in entries),
        "needs_review": sum(needs_review(e["report"]) for e in entries),
        "reviewed": sum(e.get("review") is not None for e in entries),
    }


def batch_input_name(index: int) -> str:
    """The input name of a batch's photo ``index`` (0-based, in upload order)."""
    return f"photo-{index:04d}"


__all__ = ["BATCH_JOB", "JOBS", "OrientationBatchParams", "batch_input_name", "fixed_name", "record_review",
           "run_orientation_batch", "sanitize_filename", "summary_of"]

BATCH_JOB = JobKind("orientation.batch", run_orientation_batch, OrientationBatchParams)
JOBS = (BATCH_JOB,)
