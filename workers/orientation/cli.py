"""``sweepcast orient PATH... [--write] [--force] [--yunet MODEL] [--no-text]``: find which way is up, tag JPEGs.

Without ``--write`` nothing is changed: the table says what would be done. With ``--write`` each
JPEG/WebP whose tag should change is rewritten in place (atomically; only the EXIF block
changes). Folders are searched recursively for .jpg/.jpeg/.png/.webp files.

Faces first (the paper's detector, or YuNet combined with it), then text (Tesseract OSD, when
installed); a photo neither decides clearly is rejected for review, never guessed.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from workers.common.cliutil import ProgressBar, format_table
from workers.common.images import MAX_PIXELS_ENV, max_pixels_from_env
from workers.common.models import models_dir
from workers.orientation.detect import DetectorConfig, get_detector
from workers.orientation.errors import OrientationInputError
from workers.orientation.exif import TAGGABLE_FORMATS
from workers.orientation.headers import sniff_format
from workers.orientation.job import YUNET_MODEL_ENV, configured_yunet
from workers.orientation.service import OrientationReport, analyze, orient_jpeg, plan_tag
from workers.orientation.text import TESSERACT_ENV, text_settings_from_env

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".webp")


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``orient`` command to a ``sweepcast`` sub-command parser."""
    p = subparsers.add_parser("orient", help="detect the upright rotation of photos (faces, then text) and set the "
                                            "EXIF tag",
                              description=__doc__.split("\n\n")[1].replace("\n", " "))
    p.add_argument("paths", nargs="+", type=Path, metavar="PATH", help="photos or folders of photos")
    p.add_argument("--write", action="store_true", help="write the Orientation tag into the files")
    p.add_argument("--force", action="store_true", help="replace existing tags other than 1")
    data_models = models_dir(Path(os.environ.get("SWEEPCAST_DATA_DIR", "./sweepcast-data")))
    p.add_argument("--yunet", type=Path, default=configured_yunet(data_models), metavar="MODEL",
                   help=f"YuNet ONNX model for the stronger detector (default ${YUNET_MODEL_ENV}, else the one "
                        "'sweepcast models fetch yunet' installed in the data folder)")
    p.add_argument("--method", choices=("auto", "paper", "yunet", "combined"), default="auto",
                   help="detector (auto: combined with --yunet, else paper)")
    text_on, tesseract = text_settings_from_env()
    p.add_argument("--no-text", dest="text", action="store_false", default=text_on,
                   help="faces only: do not read the text's orientation (Tesseract OSD) when no face decides")
    p.add_argument("--tesseract", default=tesseract, metavar="BINARY",
                   help=f"the tesseract binary for the text cue (default ${TESSERACT_ENV}, else 'tesseract' on PATH)")
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
        print("sweepcast orient: no .jpg, .jpeg, .png or .webp files found", file=sys.stderr)
        return 2
    try:
        detector = get_detector(DetectorConfig(method=args.method, yunet_model=args.yunet, text=args.text,
                                               tesseract=args.tesseract))
    except (ValueError, FileNotFoundError) as exc:
        print(f"sweepcast orient: {exc}", file=sys.stderr)
        return 2
    max_pixels = args.max_pixels or max_pixels_from_env()
    bar = ProgressBar("orient")
    results: list[Result] = []
    for i, path in enumerate(files):
        try:
            results.append(_one(path, detector, args, max_pixels))
        except OrientationInputError as exc:
            results.append(Result(path, None, "error", str(exc)))
        bar((i + 1) / len(files), path.name)
    bar.close()
    _print(results, args.json)
    for r in results:
        if r.error is not None:
            print(f"sweepcast orient: {r.path}: {r.error}", file=sys.stderr)
    return 2 if any(r.error is not None for r in results) else 0


@dataclass
class Result:
    path: Path
    report: OrientationReport | None
    action: str
    """What was done, or with a dry run what --write would do."""
    error: str | None = None


def _one(path: Path, detector, args: argparse.Namespace, max_pixels: int) -> Result:
    data = path.read_bytes()
    fmt = sniff_format(data)
    if fmt not in TAGGABLE_FORMATS:
        return Result(path, analyze(data, detector, max_pixels), f"none ({fmt.upper()} has no tag)")
    if not args.write:
        report = analyze(data, detector, max_pixels)
        action, value = plan_tag(report, args.force)
        return Result(path, report, f"would write {value}" if action == "written" else action)
    new_bytes, report = orient_jpeg(data, detector, args.force, max_pixels)
    if report.written:
        _replace_file(path, new_bytes)
        return Result(path, report, f"written {report.written_orientation}")
    return Result(path, report, report.action)


def _replace_file(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically, keeping its permissions."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, path.stat().st_mode & 0o7777)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _expand(paths: list[Path]) -> tuple[list[Path], list[Path]]:
    files, missing = [], []
    for path in paths:
        if path.is_dir():
            files += sorted(p for p in path.rglob("*") if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
        elif path.is_file():
            files.append(path)
        else:
            missing.append(path)
    return files, missing


def _print(results: list[Result], as_json: bool) -> None:
    if as_json:
        out = [{"path": str(r.path), "action": r.action, "error": r.error,
                "report": r.report.model_dump(mode="json") if r.report else None} for r in results]
        print(json.dumps(out, indent=2))
        return
    rows = []
    for r in results:
        if r.report is None:
            rows.append([r.path, "error", "-", "-", "-", "-", "-", r.error])
            continue
        rotation = "-" if r.report.rotation_degrees is None else f"{r.report.rotation_degrees} cw"
        rows.append([r.path, r.report.decision, rotation, r.report.orientation or "-", r.report.cue,
                     r.report.reject_reason or "-", len(r.report.faces), r.action])
    print(format_table(["file", "decision", "rotation", "EXIF", "cue", "why rejected", "faces", "action"], rows))
    decided = [r.report.decision for r in results if r.report]
    errors = sum(r.report is None for r in results)
    written = sum(bool(r.report and r.report.written) for r in results)
    print(f"\n{len(results)} photos: {decided.count('upright')} upright, {decided.count('rotated')} rotated, "
          f"{decided.count('rejected')} rejected, {errors} errors; {written} files written")
