"""What ``sweepcast orient`` remembers between runs over a library, so that a second run analyses no photo again.

A state file (JSON lines, appended as each photo is done, so a run that is interrupted keeps what it finished)
holds one row per photo analysed: the SHA-256 of its bytes, the :func:`fingerprint` of everything else that shapes
the answer (the engine's code, the detector and its model, the text cue and its data, ``force``, file or sidecar
mode), whether it has something left to write, its result, and where the file was with which size and modification
time. A later run with the same fingerprint does not analyse a photo whose bytes it has a row for
(:meth:`LibraryState.known`), and does not even read a file found where a row says with the same size and
modification time (:meth:`LibraryState.unchanged`):

- a dry run reuses any row; a run that writes reuses only rows with nothing left to write (a dry run's "would write"
  is done for real);
- a photo whose tag was written into it is remembered by the hash of its *new* bytes (the old ones are gone);
- a photo that got a sidecar is not remembered (the next run skips it because of its sidecar; if the sidecar is
  deleted, it is written again), nor is a file that could not be read (it is tried again).

At the end of a run that went through every file the file is rewritten with the rows of this run's files only.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any, Iterable, TextIO

import cv2

from workers.common.packages import package_version
from workers.orientation.detect import DetectorConfig, detector_name
from workers.orientation.library import FileStat, LibraryOptions, PathOutcome, Result, file_stat
from workers.orientation.orient import OrientationReport
from workers.orientation.textdata import text_plan
from workers.orientation.xmp import replace_file

ENGINE_DIR = Path(__file__).resolve().parent


def fingerprint(config: DetectorConfig, options: LibraryOptions) -> str:
    """A short hash of everything besides a photo's bytes that can change what a run decides or writes for it: the
    engine's code, OpenCV's and onnxruntime's versions, the detector ``config`` names (:func:`detector_name`), its
    configuration and model file, what its text cue is made of (:func:`text_plan`), and the options that change the
    answer. Found without building the engine (a run with nothing left to analyse never builds it). Raises
    ValueError for a configuration no detector can be built from."""
    model = config.yunet_model
    parts = {
        "engine": _engine_digest(),
        "opencv": cv2.__version__,
        "onnxruntime": package_version("onnxruntime"),
        "detector": detector_name(config),
        "config": config.model_dump(mode="json"),
        "model": [model.stat().st_size, model.stat().st_mtime_ns] if model is not None and model.is_file() else None,
        "text": text_plan(config.text, config.tessdata, config.wordlists),
        "force": options.force,
        "mode": options.mode,
        "naming": options.naming,
    }
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _engine_digest() -> str:
    """The engine's code as it is now (a newer release may decide differently: its rows are not reused)."""
    digest = hashlib.sha256()
    for path in sorted(ENGINE_DIR.glob("*.py")):
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


class LibraryState:
    """The state file of one library (see the module docstring): read at the start unless ``resume`` is false (then
    started afresh), appended to as photos are done, compacted by :meth:`close`."""

    def __init__(self, path: Path, fingerprint: str, resume: bool = True) -> None:
        self.path = path
        self.fingerprint = fingerprint
        self.rows: dict[str, dict[str, Any]] = {}
        """Hash -> the row of a photo with those bytes (its result; at any of its places)."""
        self._at: dict[str, tuple[str, list[int]]] = {}
        """Path -> (the hash of the photo recorded there, its size and modification time then): every place of the
        same bytes (a library holds copies of one photo in several albums)."""
        if resume:
            self._read()
        self._used: set[str] = set()
        self._hashed: set[str] = set()
        """The paths whose bytes this run hashed: their rows with other hashes are out of date."""
        path.parent.mkdir(parents=True, exist_ok=True)
        self._out: TextIO = open(path, "a" if resume else "w", encoding="utf-8")

    def _read(self) -> None:
        try:
            lines = self.path.read_text(encoding="utf-8").splitlines()
        except FileNotFoundError:
            return
        for line in lines:
            try:
                row = json.loads(line)
            except ValueError:  # the last line of a run killed while writing it
                continue
            if isinstance(row, dict) and row.get("fingerprint") == self.fingerprint and "sha256" in row:
                self._place(row)

    def _place(self, row: dict[str, Any]) -> None:
        """``row`` is what its bytes decide, and where they were found (when its size and time were known)."""
        self.rows[row["sha256"]] = row
        if row.get("stat"):
            self._at[row["path"]] = (row["sha256"], list(row["stat"]))

    def known(self, options: LibraryOptions) -> set[str]:
        """Hashes of the photos a run with ``options`` need not analyse."""
        return {sha for sha, row in self.rows.items() if not (options.changes_files and row["writes"])}

    def unchanged(self, path: Path, options: LibraryOptions) -> str | None:
        """The hash of the photo at ``path`` when a row a run with ``options`` may reuse was recorded there and the
        file still has the size and modification time it had then (it is not read); else None."""
        sha, stat = self._at.get(str(path), (None, None))
        row = self.rows.get(sha) if sha is not None else None
        if row is None or (options.changes_files and row["writes"]):
            return None
        try:
            return sha if list(file_stat(path)) == stat else None
        except OSError:
            return None

    def result(self, sha256: str, path: Path, stat: FileStat | None = None) -> Result:
        """The remembered result of the photo with these bytes, now at ``path`` (with ``stat``, when it was read: a
        photo moved or touched since is remembered where and as it is now)."""
        row = self.rows[sha256]
        self._used.add(sha256)
        self._hashed.add(str(path))
        if stat is not None and self._at.get(str(path)) != (sha256, list(stat)):
            row = {**row, "path": str(path), "stat": list(stat)}
            self._place(row)
            self._append(row)
        report = OrientationReport.model_validate(row["report"])
        return Result(path, report, f"unchanged since the last run: {row['action']}", written_to=[],
                      format=row["format"])

    def record(self, outcome: PathOutcome) -> None:
        """Remember a photo this run analysed, where its result tells what its bytes on disk now decide."""
        result = outcome.result
        if result is not None and outcome.sha256 is not None:
            self._hashed.add(str(result.path))
        if result is None or result.report is None or result.error is not None:
            return
        written = result.written_to or []
        if written == [str(result.path)] and outcome.sha256_after:  # only the photo changed: its new bytes
            sha, stat, writes = outcome.sha256_after, outcome.stat_after, False
        elif written or outcome.sha256 is None:  # a sidecar: the next run sees it
            return
        else:
            plan = result.report.write
            sha, stat = outcome.sha256, outcome.stat
            writes = result.written_to is None and plan is not None and plan.target != "none"
        row = {"sha256": sha, "fingerprint": self.fingerprint, "writes": writes, "path": str(result.path),
               "stat": list(stat) if stat else None, "format": result.format, "action": result.action,
               "report": result.report.model_dump(mode="json", exclude={"elapsed_ms"}) | {"elapsed_ms": 0.0}}
        self._place(row)
        self._used.add(sha)
        self._append(row)

    def _append(self, row: dict[str, Any]) -> None:
        self._out.write(json.dumps(row) + "\n")
        self._out.flush()

    def close(self, complete: bool, paths: Iterable[Path] = ()) -> None:
        """Close the file; after a ``complete`` run, keep only the rows of this run's photos (``paths``): one for each
        of their places whose bytes this run used or recorded, or did not hash (skipped as already tagged), and the
        rows used with no place known."""
        self._out.close()
        if not complete:
            return
        run = {str(p) for p in paths}
        unhashed = run - self._hashed
        kept = [{**self.rows[sha], "path": path, "stat": stat} for path, (sha, stat) in self._at.items()
                if path in run and (sha in self._used or path in unhashed)]
        placed = {row["sha256"] for row in kept}
        kept += [row for sha, row in self.rows.items() if sha in self._used and sha not in placed]
        replace_file(self.path, "".join(json.dumps(row) + "\n" for row in kept).encode())


def default_state_path(report_stem: Path | None, paths: list[Path]) -> Path:
    """Beside the report (``STEM.state.jsonl``) when there is one; else in the user's cache folder, one per set of
    library paths (never inside the library: organisers index what is there)."""
    if report_stem is not None:
        return report_stem.with_name(report_stem.name + ".state.jsonl")
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "sweepcast" / "orient"
    key = hashlib.sha256("\0".join(sorted(str(p.resolve()) for p in paths)).encode()).hexdigest()[:16]
    return cache / f"{key}.state.jsonl"
