"""``sweepcast orient PATH... [--write | --sidecar] [--force] [--report STEM]``: find which way is up, write it.

Without ``--write`` or ``--sidecar`` nothing is changed: the table says what would be done. With
``--write`` each photo whose orientation should change gets it where its format keeps it (JPEG,
WebP, TIFF: the EXIF tag; PNG: its eXIf chunk; atomically, every other byte kept) and HEIF, AVIF
and RAW files, which are never written, an XMP sidecar. With ``--sidecar`` every photo gets a
sidecar and no photo changes. Folders are searched recursively. Photos already tagged (an
orientation other than 1 in the file or its sidecar) are skipped unless ``--force``, so a second
run changes nothing. The report (``--report``: STEM.json and STEM.csv) lists the decision, cue,
confidence, conflicts and needs_review of each file.

Faces first (the paper's detector, or YuNet combined with it), then text (Tesseract OSD, when
installed); a photo neither decides clearly is rejected for review, never guessed.
"""
from __future__ import annotations

import argparse
import csv
import io
import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path

from workers.common.cliutil import ProgressBar, format_table
from workers.common.images import MAX_PIXELS_ENV, max_pixels_from_env
from workers.common.models import models_dir
from workers.orientation.detect import DetectorConfig, get_detector
from workers.orientation.errors import OrientationInputError
from workers.orientation.exiftool import ExifToolError, ExifToolUnavailable
from workers.orientation.headers import RAW_EXTENSIONS, parse_header
from workers.orientation.job import YUNET_MODEL_ENV, configured_yunet
from workers.orientation.exif import VALID_ORIENTATIONS
from workers.orientation.metadata import inspect, target_for
from workers.orientation.orient import OrientationReport, analyze, orient_file
from workers.orientation.text import text_settings_from_env
from workers.orientation.xmp import MAX_SIDECAR_BYTES, existing_sidecars, replace_file, sidecar_path

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".jpe", ".png", ".webp", ".tif", ".tiff", ".heic", ".heif", ".hif", ".avif",
                  *sorted(RAW_EXTENSIONS))
REPORT_COLUMNS = ("path", "format", "decision", "cue", "confidence", "rotation_degrees", "orientation",
                  "existing_orientation", "action", "target", "written_to", "conflicts", "needs_review",
                  "reject_reason", "error")


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``orient`` command to a ``sweepcast`` sub-command parser."""
    p = subparsers.add_parser("orient", help="detect the upright rotation of photos (faces, then text) and write "
                                            "it into the files or XMP sidecars",
                              description=__doc__.split("\n\n")[1].replace("\n", " "))
    p.add_argument("paths", nargs="+", type=Path, metavar="PATH", help="photos or folders of photos (a photo library)")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--write", action="store_true", help="write the orientation into the files (JPEG, WebP, TIFF, "
                                                          "PNG); HEIF, AVIF and RAW get a sidecar")
    mode.add_argument("--sidecar", action="store_true", help="write XMP sidecars only; no photo changes")
    p.add_argument("--sidecar-name", choices=("ext", "stem"), default="ext",
                   help="sidecar file name: ext = photo.jpg.xmp (digiKam, darktable; default), stem = photo.xmp "
                        "(Lightroom); Immich and PhotoPrism read both")
    p.add_argument("--force", action="store_true", help="analyse photos already tagged and replace orientations "
                                                        "other than 1")
    p.add_argument("--report", type=Path, metavar="STEM", default=None,
                   help="write the report to STEM.json and STEM.csv (keep it outside the library)")
    data_models = models_dir(Path(os.environ.get("SWEEPCAST_DATA_DIR", "./sweepcast-data")))
    p.add_argument("--yunet", type=Path, default=configured_yunet(data_models), metavar="MODEL",
                   help=f"YuNet ONNX model for the stronger detector (default ${YUNET_MODEL_ENV}, else the one "
                        "'sweepcast models fetch yunet' installed in the data folder)")
    p.add_argument("--method", choices=("auto", "paper", "yunet", "combined"), default="auto",
                   help="detector (auto: combined with --yunet, else paper)")
    text_on, tessdata, wordlists = text_settings_from_env()
    p.add_argument("--no-text", dest="text", action="store_false", default=text_on,
                   help="faces only: do not read the text's orientation when no face decides")
    p.add_argument("--tessdata", type=Path, default=tessdata, metavar="FOLDER",
                   help="Tesseract's model folder for the text cue (default $SWEEPCAST_ORIENTATION_TESSDATA, else "
                        "Debian's when installed, else the one pip installed)")
    p.add_argument("--wordlists", type=Path, default=wordlists, metavar="FOLDER",
                   help="the word lists whose words the text cue accepts (default $SWEEPCAST_ORIENTATION_WORDLISTS, "
                        "else /usr/share/dict when it holds lists, else wordfreq's)")
    p.add_argument("--max-pixels", type=int, default=None,
                   help=f"refuse images larger than this (default ${MAX_PIXELS_ENV} or 64,000,000)")
    p.add_argument("--json", action="store_true", help="print the reports as JSON instead of a table")
    p.set_defaults(func=_orient)


def _orient(args: argparse.Namespace) -> int:
    files, missing = _expand(args.paths)
    for path in missing:
        print(f"sweepcast orient: {path}: no such file or folder", file=sys.stderr)
    if missing:
        return 2
    if not files:
        print(f"sweepcast orient: no photos found ({', '.join(IMAGE_SUFFIXES[:11])}, RAW)", file=sys.stderr)
        return 2
    try:
        detector = get_detector(DetectorConfig(method=args.method, yunet_model=args.yunet, text=args.text,
                                               tessdata=args.tessdata, wordlists=args.wordlists))
    except (ValueError, FileNotFoundError) as exc:
        print(f"sweepcast orient: {exc}", file=sys.stderr)
        return 2
    max_pixels = args.max_pixels or max_pixels_from_env()
    bar = ProgressBar("orient")
    results: list[Result] = []
    for i, path in enumerate(files):
        try:
            results.append(_one(path, detector, args, max_pixels))
        except (OrientationInputError, ExifToolUnavailable, ExifToolError) as exc:
            results.append(Result(path, None, "error", error=str(exc)))
        bar((i + 1) / len(files), path.name)
    bar.close()
    _print(results, args.json)
    if args.report is not None:
        write_report(results, args.report)
    for r in results:
        if r.error is not None:
            print(f"sweepcast orient: {r.path}: {r.error}", file=sys.stderr)
    return 2 if any(r.error is not None for r in results) else 0


@dataclass
class Result:
    path: Path
    report: OrientationReport | None
    action: str
    """What was done, or with a dry run what --write/--sidecar would do."""
    written_to: list[str] | None = None
    """The files written (the photo, its sidecar, sidecars brought into agreement)."""
    error: str | None = None
    format: str | None = None
    existing: int | None = None
    conflicts: list[str] | None = None


def _sidecar_texts(path: Path) -> dict[str, bytes]:
    """The sidecars beside ``path`` (name -> bytes), those over :data:`MAX_SIDECAR_BYTES` left out."""
    return {p.name: p.read_bytes() for p in existing_sidecars(path) if p.stat().st_size <= MAX_SIDECAR_BYTES}


def _one(path: Path, detector, args: argparse.Namespace, max_pixels: int) -> Result:
    data = path.read_bytes()
    header = parse_header(data, path.name)
    mode = "sidecar" if args.sidecar else "file"
    naming = args.sidecar_name
    sidecars = _sidecar_texts(path)
    insp = inspect(data, header, sidecars)
    target, _ = target_for(header.format, mode, insp)
    own = insp.sidecars.get(sidecar_path(path, naming).name) if target == "xmp-sidecar" else None
    existing = own.value if own is not None and own.value in VALID_ORIENTATIONS else insp.shown()
    if not args.force and existing in VALID_ORIENTATIONS and existing != 1:
        return Result(path, None, f"skipped: already tagged ({existing})", format=header.format, existing=existing,
                      conflicts=insp.conflicts())
    if not (args.write or args.sidecar):
        report = analyze(data, detector, max_pixels, path.name, sidecars, mode, naming, args.force, inspection=insp)
        plan = report.write
        action = (f"would write {plan.value} to {_target_text(plan.target, plan.where)}" if plan.target != "none"
                  else _plain(report))
        return Result(path, report, action, format=header.format)
    outcome = orient_file(data, detector, args.force, max_pixels, path.name, sidecars, mode, naming, inspection=insp)
    written: list[str] = []
    if outcome.photo is not None:
        replace_file(path, outcome.photo)
        written.append(str(path))
    if outcome.sidecar is not None and outcome.sidecar_name:
        replace_file(path.with_name(outcome.sidecar_name), outcome.sidecar)
        written.append(str(path.with_name(outcome.sidecar_name)))
    for name, text in outcome.updated_sidecars.items():
        replace_file(path.with_name(name), text)
        written.append(str(path.with_name(name)))
    report = outcome.report
    action = (f"written {report.written_orientation} to {_target_text(report.write.target, report.write.where)}"
              if report.written else report.action)
    return Result(path, report, action, written_to=written, format=header.format)


def _target_text(target: str, where: str | None) -> str:
    return {"exif-ifd0": "EXIF", "png-exif": "PNG eXIf"}.get(target, f"sidecar {where}")


def _plain(report: OrientationReport) -> str:
    """What a dry run would do when it writes nothing: the plan's last note."""
    return report.write.note.split("; ")[-1] if report.write and report.write.note else "nothing to write"


def _expand(paths: list[Path]) -> tuple[list[Path], list[Path]]:
    files, missing = [], []
    for path in paths:
        if path.is_dir():
            files += sorted(p for p in path.rglob("*") if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
                            and not p.name.startswith("."))
        elif path.is_file():
            files.append(path)
        else:
            missing.append(path)
    return files, missing


def report_rows(results: list[Result]) -> list[dict[str, object]]:
    """One flat row per file (the CSV's columns, :data:`REPORT_COLUMNS`)."""
    rows = []
    for r in results:
        rep = r.report
        conflicts = rep.conflicts if rep is not None else (r.conflicts or [])
        rows.append({
            "path": str(r.path), "format": rep.format if rep else r.format,
            "decision": rep.decision if rep else ("skipped" if r.error is None else "error"),
            "cue": rep.cue if rep else None, "confidence": rep.confidence if rep else None,
            "rotation_degrees": rep.rotation_degrees if rep else None, "orientation": rep.orientation if rep else None,
            "existing_orientation": rep.existing_orientation if rep else r.existing, "action": r.action,
            "target": rep.write.target if rep and rep.write else None, "written_to": r.written_to or [],
            "conflicts": conflicts, "needs_review": bool(rep.needs_review) if rep else r.error is not None,
            "reject_reason": rep.reject_reason if rep else None, "error": r.error,
        })
    return rows


def write_report(results: list[Result], stem: Path) -> None:
    """``stem``.json (rows plus each full report) and ``stem``.csv (the rows), each written atomically."""
    rows = report_rows(results)
    full = [{**row, "report": r.report.model_dump(mode="json", exclude={"elapsed_ms"}) if r.report else None}
            for row, r in zip(rows, results)]
    stem.parent.mkdir(parents=True, exist_ok=True)
    replace_file(stem.with_name(stem.name + ".json"), (json.dumps(full, indent=2) + "\n").encode())
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=REPORT_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("; ".join(map(str, v)) if isinstance(v, list) else v) for k, v in row.items()})
    replace_file(stem.with_name(stem.name + ".csv"), buf.getvalue().encode())


def _print(results: list[Result], as_json: bool) -> None:
    if as_json:
        out = [{"path": str(r.path), "action": r.action, "error": r.error, "written_to": r.written_to,
                "report": r.report.model_dump(mode="json") if r.report else None} for r in results]
        print(json.dumps(out, indent=2))
        return
    rows = []
    for r in results:
        if r.report is None:
            rows.append([r.path, r.format or "-", "error" if r.error else "skipped", "-", "-", "-", "-",
                         r.error or r.action])
            continue
        rotation = "-" if r.report.rotation_degrees is None else f"{r.report.rotation_degrees} cw"
        rows.append([r.path, r.report.format, r.report.decision, rotation, r.report.orientation or "-", r.report.cue,
                     r.report.reject_reason or ("conflict" if r.report.conflicts else "-"), r.action])
    print(format_table(["file", "format", "decision", "rotation", "EXIF", "cue", "review", "action"], rows))
    decided = [r.report.decision for r in results if r.report]
    errors = sum(r.error is not None for r in results)
    skipped = sum(r.report is None and r.error is None for r in results)
    written = sum(bool(r.written_to) for r in results)
    print(f"\n{len(results)} photos: {decided.count('upright')} upright, {decided.count('rotated')} rotated, "
          f"{decided.count('rejected')} rejected, {skipped} skipped (already tagged), {errors} errors; "
          f"{written} files written")
