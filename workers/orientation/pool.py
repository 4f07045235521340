"""The files of a library analysed by a pool of processes, each result handed back as it comes.

``jobs`` processes (spawned: nothing of this process is shared with them but what is passed) each build the
detector once and run :func:`workers.orientation.library.orient_path` on one file at a time, with OpenCV on one
thread (the processes share the cores out, one each). At most ``IN_FLIGHT_PER_JOB`` files per process are handed
out ahead, so that a run that is stopped has little under way: :meth:`FilePool.stop` lets the files under way finish
(a file is never left half-written) and hands their outcomes back. With ``jobs=1`` the files are analysed in this
process, with the caller's detector.
"""
from __future__ import annotations

import concurrent.futures
import multiprocessing
import signal
from pathlib import Path
from typing import AbstractSet, Iterator, Sequence

import cv2

from workers.orientation.detect import DetectorConfig, OrientationDetector, get_detector
from workers.orientation.errors import OrientationInputError
from workers.orientation.exiftool import ExifToolError, ExifToolUnavailable
from workers.orientation.library import LibraryOptions, PathOutcome, Result, orient_path

IN_FLIGHT_PER_JOB = 4

_worker: dict[str, object] = {}


class FilePool:
    """Use as a context manager: :meth:`outcomes` yields ``(i, outcome of files[i])`` in the order they finish (a file
    that cannot be read: a result with its error); after an interruption :meth:`stop` yields those still under way.
    ``detector``: the one to use in this process (``jobs=1``)."""

    def __init__(self, files: Sequence[Path], options: LibraryOptions, known: AbstractSet[str], jobs: int,
                 config: DetectorConfig, detector: OrientationDetector | None = None) -> None:
        self.files, self.options, self.known, self.config = files, options, frozenset(known), config
        self.jobs = max(1, min(jobs, len(files)))  # no more processes than files (none started for none)
        self.detector = detector
        self._pool: concurrent.futures.ProcessPoolExecutor | None = None
        self._running: dict[concurrent.futures.Future, int] = {}

    def __enter__(self) -> "FilePool":
        if self.jobs > 1:
            self._pool = concurrent.futures.ProcessPoolExecutor(
                self.jobs, mp_context=multiprocessing.get_context("spawn"), initializer=_start_worker,
                initargs=(self.config, self.options, self.known))
        return self

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)

    def outcomes(self) -> Iterator[tuple[int, PathOutcome]]:
        if self._pool is None:
            detector = self.detector or get_detector(self.config)
            for i, path in enumerate(self.files):
                yield i, _guarded(path, detector, self.options, self.known)
            return
        queue = iter(enumerate(self.files))
        while True:
            for i, path in queue:
                self._running[self._pool.submit(_analyse, path)] = i
                if len(self._running) >= self.jobs * IN_FLIGHT_PER_JOB:
                    break
            if not self._running:
                return
            done, _ = concurrent.futures.wait(self._running, return_when=concurrent.futures.FIRST_COMPLETED)
            for future in done:
                yield self._running.pop(future), future.result()

    def stop(self) -> Iterator[tuple[int, PathOutcome]]:
        """Start no other file; the outcomes of those under way as they finish."""
        for future in list(self._running):
            if future.cancel():
                del self._running[future]
        for future in concurrent.futures.as_completed(list(self._running)):
            yield self._running.pop(future), future.result()


def _start_worker(config: DetectorConfig, options: LibraryOptions, known: frozenset[str]) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle: it lets these finish
    cv2.setNumThreads(1)
    _worker.update(detector=get_detector(config), options=options, known=known)


def _analyse(path: Path) -> PathOutcome:
    return _guarded(path, _worker["detector"], _worker["options"], _worker["known"])  # type: ignore[arg-type]


def _guarded(path: Path, detector: OrientationDetector, options: LibraryOptions,
             known: AbstractSet[str]) -> PathOutcome:
    try:
        return orient_path(path, detector, options, known)
    except (OrientationInputError, ExifToolUnavailable, ExifToolError) as exc:
        return PathOutcome(Result(path, None, "error", error=str(exc)))
