"""``sweepcast orient PATH... [--write | --sidecar] [--force] [--report STEM] [--jobs N]``: find which way is up,
write it.

Without ``--write`` or ``--sidecar`` nothing is changed: the table says what would be done. With
``--write`` each photo whose orientation should change gets it where its format keeps it (JPEG,
WebP, TIFF: the EXIF tag; PNG: its eXIf chunk; atomically, every other byte kept) and HEIF, AVIF
and RAW files, which are never written, an XMP sidecar. With ``--sidecar`` every photo gets a
sidecar and no photo changes. Folders are searched recursively. Photos already tagged (an
orientation other than 1 in the file or its sidecar) are skipped unless ``--force``, so a second
run changes nothing. The report (``--report``: STEM.json and STEM.csv) lists the decision, cue,
confidence, conflicts and needs_review of each file, in the order of the files.

A library is analysed by ``--jobs`` processes (default: every core this process may use), with a progress line and
the time left. A run remembers what it decided (a state file, :mod:`workers.orientation.resume`: beside the report,
else in the user's cache folder), so a run that was interrupted, or the next one, does not analyse again a photo
whose bytes it already decided with the same settings; ``--no-resume`` starts over.

Faces first (the paper's detector, or YuNet combined with it), then text (Tesseract OSD, when
installed); a photo neither decides clearly is rejected for review, never guessed.
"""
from __future__ import annotations

import argparse
import concurrent.futures
import concurrent.futures.process  # BrokenProcessPool, caught in _orient_library
import csv
import io
import json
import os
import sys
from pathlib import Path

from workers.common.cliutil import ProgressBar, format_table
from workers.common.cores import usable_cores
from workers.common.images import MAX_PIXELS_ENV, max_pixels_from_env
from workers.common.models import models_dir
from workers.common.pace import Pace
from workers.orientation.detect import DetectorConfig, face_detector, get_detector
from workers.orientation.headers import RAW_EXTENSIONS
from workers.orientation.job import YUNET_MODEL_ENV, configured_yunet
from workers.orientation.library import LibraryOptions, PathOutcome, Result
from workers.orientation.pool import FilePool
from workers.orientation.resume import LibraryState, default_state_path, fingerprint
from workers.orientation.text import text_settings_from_env
from workers.orientation.xmp import replace_file

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
    p.add_argument("--jobs", type=_positive, default=usable_cores(), metavar="N",
                   help="processes that analyse photos at once (1: this one; N > 1: N helpers this one hands photos "
                        f"to; default: the cores this process may use, {usable_cores()} here)")
    p.add_argument("--no-resume", dest="resume", action="store_false",
                   help="analyse every photo again, forgetting what earlier runs decided")
    p.add_argument("--state", type=Path, default=None, metavar="FILE",
                   help="where a run keeps what it decided, for the next one (default: STEM.state.jsonl beside "
                        "--report, else a file in ~/.cache/sweepcast/orient for these PATHs)")
    p.set_defaults(func=_orient)


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, not {value}")
    return value


def _orient(args: argparse.Namespace) -> int:
    try:
        return _orient_library(args)
    except KeyboardInterrupt:  # before the photos (the detector loading): nothing to keep
        print("\nsweepcast orient: interrupted", file=sys.stderr)
        return 130


def _orient_library(args: argparse.Namespace) -> int:
    files, missing = _expand(args.paths)
    for path in missing:
        print(f"sweepcast orient: {path}: no such file or folder", file=sys.stderr)
    if missing:
        return 2
    if not files:
        print(f"sweepcast orient: no photos found ({', '.join(IMAGE_SUFFIXES[:11])}, RAW)", file=sys.stderr)
        return 2
    config = DetectorConfig(method=args.method, yunet_model=args.yunet, text=args.text, tessdata=args.tessdata,
                            wordlists=args.wordlists)
    options = LibraryOptions(write=args.write, sidecar=args.sidecar, naming=args.sidecar_name, force=args.force,
                             max_pixels=args.max_pixels or max_pixels_from_env())
    try:  # the engine itself is built only when a photo needs it (_run): a library already done costs no second
        key = fingerprint(config, options)
    except ValueError as exc:
        print(f"sweepcast orient: {exc}", file=sys.stderr)
        return 2
    state = LibraryState(args.state or default_state_path(args.report, args.paths), key, args.resume)
    results: list[Result | None] = [None] * len(files)
    try:
        _run(files, options, state, args.jobs, config, results)
    except EngineUnavailable as exc:
        state.close(complete=False)
        print(f"sweepcast orient: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        state.close(complete=False)
        print(f"\nsweepcast orient: interrupted after {_count(results)} of {len(files)} photos; what they decided is "
              f"kept in {state.path}: the same command goes on from there", file=sys.stderr)
        return 130
    except concurrent.futures.process.BrokenProcessPool:
        state.close(complete=False)
        print(f"sweepcast orient: a worker process died (killed, or out of memory) after {_count(results)} of "
              f"{len(files)} photos; the same command goes on from there (--jobs 1 holds the least memory)",
              file=sys.stderr)
        return 1
    state.close(complete=True, paths=files)
    done = [r for r in results if r is not None]
    _print(done, args.json)
    if args.report is not None:
        write_report(done, args.report)
    for r in done:
        if r.error is not None:
            print(f"sweepcast orient: {r.path}: {r.error}", file=sys.stderr)
    return 2 if any(r.error is not None for r in done) else 0


def _count(results: list[Result | None]) -> int:
    return sum(r is not None for r in results)


class EngineUnavailable(Exception):
    """The engine of the run's configuration cannot be built (a YuNet model missing or damaged)."""


def _run(files: list[Path], options: LibraryOptions, state: LibraryState, jobs: int, config: DetectorConfig,
         results: list[Result | None]) -> None:
    """Analyse ``files`` (``results[i]`` filled in as each is done), remembering each in ``state``, with a progress
    bar whose time left counts only the photos still to analyse; the engine is built once the photos unchanged since
    a run decided them are set aside, and only when others remain (else EngineUnavailable when it cannot be).
    Interrupted (Ctrl-C), it lets the photos under way finish, keeps what they decided, and raises
    KeyboardInterrupt."""
    bar = ProgressBar("orient")
    pace = Pace(len(files))

    def take(i: int, outcome: PathOutcome) -> None:
        if outcome.result is None:  # decided by an earlier run: no time spent on it now
            results[i] = state.result(outcome.sha256, files[i], outcome.stat)
            pace.skip()
        else:
            results[i] = outcome.result
            state.record(outcome)
            pace.add()
        bar((pace.done + len(files) - pace.todo) / len(files), files[i].name, pace.seconds_left())

    todo = []
    for i, path in enumerate(files):  # unchanged since a run decided them: not even read
        sha = state.unchanged(path, options)
        if sha is None:
            todo.append(i)
        else:
            take(i, PathOutcome(None, sha))
    if not todo:
        bar.close()
        return
    with FilePool([files[i] for i in todo], options, state.known(options), jobs, config) as pool:
        try:  # the helpers build their engines; this process checks the configuration (tenths of a second)
            if pool.helpers:
                face_detector(config)
            else:
                pool.detector = get_detector(config)
        except (ValueError, FileNotFoundError) as exc:
            bar.close()
            raise EngineUnavailable(str(exc)) from None
        try:
            for k, outcome in pool.outcomes():
                take(todo[k], outcome)
        except KeyboardInterrupt:
            bar.close()
            print("sweepcast orient: interrupted; letting the photos under way finish (Ctrl-C again: at once)",
                  file=sys.stderr)
            for k, outcome in pool.stop():
                take(todo[k], outcome)
            raise
    bar.close()


def _expand(paths: list[Path]) -> tuple[list[Path], list[Path]]:
    """The photos under ``paths`` in order, each once (two processes must never write one file), and the paths that
    do not exist."""
    files, missing, seen = [], [], set()
    for path in paths:
        if path.is_dir():
            found = sorted(p for p in path.rglob("*") if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
                           and not p.name.startswith("."))
        elif path.is_file():
            found = [path]
        else:
            missing.append(path)
            continue
        for p in found:
            if (real := p.resolve()) not in seen:
                seen.add(real)
                files.append(p)
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
