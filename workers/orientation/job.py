"""The batch job: fix the orientation tag of many uploaded photos.

Inputs are named ``photo-0000``, ``photo-0001``, ... with ``input_meta[name]["filename"]`` the
original file name. Results:

- ``report.json``: a list with one entry per photo, in input order:
  ``{"index", "input", "filename", "report": OrientationReport | null, "error": {"code", "message"} | null,
  "fixed_file": "fixed/0003-IMG_1234.jpg" | null, "note": str | null, "thumbnail": "review/0003.jpg" | null,
  "review": null}`` (``review``: a person's decision, added by the review page's API:
  :func:`record_review`);
- ``review/<index>.jpg``: a small thumbnail of each photo that needs a person (rejected, or orientations that
  conflict: :func:`workers.orientation.review.needs_review`), for the review page (``/review/<job id>``);
- ``fixed/<index>-<sanitised name>.<ext>``: each photo (JPEG, WebP, TIFF, PNG) whose tag was written;
- ``fixed/<index>-<sanitised name>.<ext>.xmp``: the XMP sidecar of each HEIF, AVIF or RAW photo (or of
  every photo with ``sidecar``) whose orientation was written.

A photo that cannot be read is reported in its entry and the others are still processed; the job
reports one progress event per photo. The YuNet model and the pixel limit come from the worker's
environment (``SWEEPCAST_ORIENTATION_YUNET_MODEL``, ``SWEEPCAST_MAX_IMAGE_PIXELS``), never from
the request.
"""
from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from workers.common.jobctx import JobContext, JobInputError
from workers.orientation.detect import Method, OrientationDetector, detector_config, get_detector
from workers.orientation.errors import OrientationInputError
from workers.orientation.exiftool import ExifToolError, ExifToolUnavailable
from workers.orientation.headers import sniff_format
from workers.orientation.review import ChoiceWrite, needs_review, thumbnail
from workers.orientation.orient import analyze, orient_file
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
                                         "on); false: faces only, which saves about 1-3 s of CPU per photo "
                                         "without a face")


def configured_yunet(models_folder: Path | None) -> Path | None:
    """The YuNet model ``$SWEEPCAST_ORIENTATION_YUNET_MODEL`` names, else the one installed in
    ``models_folder``, else None."""
    return worker_settings().yunet_model(models_folder)


def run_orientation_batch(ctx: JobContext) -> dict[str, Any]:
    """Analyse every ``photo-NNNN`` input, tag the JPEGs, write ``report.json`` and ``fixed/*``."""
    params = OrientationBatchParams.model_validate(ctx.params)
    names = sorted(ctx.inputs)
    if not names:
        raise JobInputError("the batch has no photos")
    try:
        config = detector_config(ctx.settings, ctx.settings.models_dir, params.method)
        detector = get_detector(config.model_copy(update={"text": config.text and params.text}))
    except ValueError as exc:
        raise JobInputError(str(exc)) from None
    max_pixels = ctx.settings.max_image_pixels
    entries = []
    for index, name in enumerate(names):
        filename = str(ctx.input_meta.get(name, {}).get("filename") or name)
        entry = _process(ctx, index, name, filename, detector, params, max_pixels)
        entries.append(entry)
        outcome = _outcome(entry)
        ctx.progress((index + 1) / len(names), f"photo {index + 1}/{len(names)} {filename}: {outcome}")
    ctx.write_result("report.json", json.dumps(entries, indent=2).encode())
    return summary_of(entries)


def _process(ctx: JobContext, index: int, name: str, filename: str, detector: OrientationDetector,
             params: OrientationBatchParams, max_pixels: int) -> dict[str, Any]:
    entry: dict[str, Any] = {"index": index, "input": name, "filename": filename, "report": None, "error": None,
                             "fixed_file": None, "note": None, "thumbnail": None, "review": None}
    try:
        data = ctx.read_input(name)
        fmt = sniff_format(data, filename)
        mode = "sidecar" if params.sidecar else "file"
        if params.write:
            outcome = orient_file(data, detector, params.force, max_pixels, filename, mode=mode)
            report = outcome.report
            stem = fixed_name(index, filename, fmt)
            if outcome.photo is not None:
                entry["fixed_file"] = stem
                ctx.write_result(stem, outcome.photo)
            elif outcome.sidecar is not None:
                entry["fixed_file"] = stem + ".xmp"
                ctx.write_result(entry["fixed_file"], outcome.sidecar)
            if report.write is not None and report.write.note:
                entry["note"] = report.write.note
        else:
            report = analyze(data, detector, max_pixels, filename, mode=mode)
        entry["report"] = report.model_dump(mode="json")
        if needs_review(entry["report"]):
            entry["thumbnail"] = review_thumbnail_name(index)
            ctx.write_result(entry["thumbnail"], thumbnail(data, filename, max_pixels))
    except OrientationInputError as exc:
        entry["error"] = {"code": exc.code, "message": str(exc)}
    except (ExifToolUnavailable, ExifToolError) as exc:
        entry["error"] = {"code": "metadata_tool", "message": str(exc)}
    return entry


def review_thumbnail_name(index: int) -> str:
    return f"review/{index:04d}.jpg"


def fixed_name(index: int, filename: str, fmt: str) -> str:
    """The result name of photo ``index``'s fixed file (its sidecar adds ``.xmp``)."""
    return f"fixed/{index:04d}-{sanitize_filename(filename)}.{_EXT[fmt]}"


def record_review(entry: dict[str, Any], rotation: int | None, reviewer: str, at: str,
                  written: ChoiceWrite | None, fixed_file: str | None) -> dict[str, Any]:
    """``entry`` (a report.json entry) with a person's decision: the turn (None: left as it is), who, when, what was
    written where. The engine's own report stays as it was, beside it."""
    review = {"decided_by": "person", "reviewer": reviewer, "at": at, "rotation_degrees": rotation,
              "action": "left_as_is" if written is None else "written",
              "orientation": written.orientation if written else None,
              "target": written.target if written else "none", "fixed_file": fixed_file}
    return {**entry, "review": review, "fixed_file": fixed_file if written else entry.get("fixed_file")}


_EXT = {"jpeg": "jpg", "webp": "webp", "tiff": "tif", "png": "png", "heif": "heic", "avif": "avif", "raw": "raw"}


def _outcome(entry: dict[str, Any]) -> str:
    """The progress line's word for one photo: the decision and its cue, why it needs review, or the error."""
    report = entry["report"]
    if report is None:
        return f"error: {entry['error']['code']}"
    if report["needs_review"]:
        return f"rejected ({report['reject_reason']}), needs review"
    return f"{report['decision']} by {report['cue']}"


def sanitize_filename(filename: str, limit: int = 80) -> str:
    """A safe file stem from an uploaded name: last path component, no extension, [A-Za-z0-9._-] only."""
    base = re.split(r"[\\/]", filename)[-1]
    stem = base.rsplit(".", 1)[0] if "." in base.lstrip(".") else base
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", stem).strip("._-")
    return safe[:limit] or "photo"


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


BATCH_JOB = JobKind("orientation.batch", run_orientation_batch, OrientationBatchParams)
JOBS = (BATCH_JOB,)
