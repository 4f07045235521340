"""One file of a photo library on disk: read it, skip it or analyse it, write its orientation beside or into it.

:func:`orient_path` is what ``sweepcast orient`` does for each file, in whichever process runs it
(:mod:`workers.orientation.pool`). It hashes the file's bytes (SHA-256) so that a later run can recognise a photo it
already decided with the same bytes (:mod:`workers.orientation.resume`): a photo whose hash is in ``known`` is not
analysed again. The stat of the bytes it hashed comes back too: a later run that finds the file with the same stat
need not even read it.
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import AbstractSet

from workers.orientation.detect import OrientationDetector
from workers.orientation.exif import VALID_ORIENTATIONS
from workers.orientation.headers import parse_header
from workers.orientation.metadata import inspect, target_for
from workers.orientation.orient import OrientationReport, analyze, orient_file
from workers.orientation.xmp import MAX_SIDECAR_BYTES, existing_sidecars, replace_file, sidecar_path


@dataclass(frozen=True)
class LibraryOptions:
    """What a run over a library does with each file (the CLI's flags)."""

    write: bool = False
    """Write the orientation into the files that hold it (and sidecars for the others)."""
    sidecar: bool = False
    """Write XMP sidecars only; no photo changes."""
    naming: str = "ext"
    """Sidecar names: ``ext`` (photo.jpg.xmp) or ``stem`` (photo.xmp)."""
    force: bool = False
    """Analyse photos already tagged, and replace orientations other than 1."""
    max_pixels: int = 64_000_000

    @property
    def changes_files(self) -> bool:
        return self.write or self.sidecar

    @property
    def mode(self) -> str:
        return "sidecar" if self.sidecar else "file"


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


FileStat = tuple[int, int]
"""(size in bytes, modification time in ns) of a file: a file whose stat is unchanged is taken to hold the same
bytes (as rsync and git do), so a run need not read it to recognise it."""


@dataclass
class PathOutcome:
    """What :func:`orient_path` did with one file: its result (None: its hash is ``known``, nothing was done), the
    SHA-256 and stat of its bytes as read, and of its new bytes when the tag was written into it."""

    result: Result | None
    sha256: str | None = None
    stat: FileStat | None = None
    sha256_after: str | None = None
    stat_after: FileStat | None = None


def sha256_of(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def file_stat(path: Path) -> FileStat:
    st = path.stat()
    return st.st_size, st.st_mtime_ns


def _read(path: Path) -> tuple[bytes, FileStat]:
    """The file's bytes and the stat of the file they were read from."""
    with open(path, "rb") as f:
        st = os.fstat(f.fileno())
        return f.read(), (st.st_size, st.st_mtime_ns)


def orient_path(path: Path, detector: OrientationDetector, options: LibraryOptions,
                known: AbstractSet[str] = frozenset()) -> PathOutcome:
    """Skip ``path`` when it is already tagged (unless ``force``) or its bytes' hash is in ``known``; else analyse it
    and, as ``options`` say, write its orientation. Raises InputError subclasses for files that cannot be
    read, ExifToolUnavailable / ExifToolError where a write needs ExifTool."""
    data, stat = _read(path)
    header = parse_header(data, path.name)
    sidecars = _sidecar_texts(path)
    insp = inspect(data, header, sidecars)
    target, _ = target_for(header.format, options.mode, insp)
    own = insp.sidecars.get(sidecar_path(path, options.naming).name) if target == "xmp-sidecar" else None
    existing = own.value if own is not None and own.value in VALID_ORIENTATIONS else insp.shown()
    if not options.force and existing in VALID_ORIENTATIONS and existing != 1:
        return PathOutcome(Result(path, None, f"skipped: already tagged ({existing})", format=header.format,
                                  existing=existing, conflicts=insp.conflicts()))
    digest = sha256_of(data)
    if digest in known:
        return PathOutcome(None, digest, stat)
    if not options.changes_files:
        report = analyze(data, detector, options.max_pixels, path.name, sidecars, options.mode, options.naming,
                         options.force, inspection=insp)
        plan = report.write
        action = (f"would write {plan.value} to {_target_text(plan.target, plan.where)}" if plan.target != "none"
                  else _plain(report))
        return PathOutcome(Result(path, report, action, format=header.format), digest, stat)
    outcome = orient_file(data, detector, options.force, options.max_pixels, path.name, sidecars, options.mode,
                          options.naming, inspection=insp)
    written: list[str] = []
    after, stat_after = None, None
    if outcome.photo is not None:
        replace_file(path, outcome.photo)
        written.append(str(path))
        after, stat_after = sha256_of(outcome.photo), file_stat(path)
    if outcome.sidecar is not None and outcome.sidecar_name:
        replace_file(path.with_name(outcome.sidecar_name), outcome.sidecar)
        written.append(str(path.with_name(outcome.sidecar_name)))
    for name, text in outcome.updated_sidecars.items():
        replace_file(path.with_name(name), text)
        written.append(str(path.with_name(name)))
    report = outcome.report
    action = (f"written {report.written_orientation} to {_target_text(report.write.target, report.write.where)}"
              if report.written else report.action)
    return PathOutcome(Result(path, report, action, written_to=written, format=header.format), digest, stat, after,
                       stat_after)


def _sidecar_texts(path: Path) -> dict[str, bytes]:
    """The sidecars beside ``path`` (name -> bytes), those over :data:`MAX_SIDECAR_BYTES` left out."""
    return {p.name: p.read_bytes() for p in existing_sidecars(path) if p.stat().st_size <= MAX_SIDECAR_BYTES}


def _target_text(target: str, where: str | None) -> str:
    return {"exif-ifd0": "EXIF", "png-exif": "PNG eXIf"}.get(target, f"sidecar {where}")


def _plain(report: OrientationReport) -> str:
    """What a dry run would do when it writes nothing: the plan's last note."""
    return report.write.note.split("; ")[-1] if report.write and report.write.note else "nothing to write"
