"""The files of a library analysed by this process and a pool of helper processes, each result handed back as it
comes.

With ``jobs`` N, this process and N-1 helpers (spawned: nothing of this process is shared with them but what is
passed) analyse files at once, each running :func:`workers.orientation.library.orient_path` on one file at a time
with its own detector, built once, and OpenCV on one thread (the processes share the cores out, one each). This
process works too rather than only waiting on the others: its detector is already built (the run needed it to check
the configuration and to fingerprint its answers), and the helpers, which take a second or two to import and build
theirs, start while it analyses the first photos. At most ``IN_FLIGHT_PER_HELPER`` files per helper are handed out
ahead, so that a run that is stopped has little under way: :meth:`FilePool.stop` lets the files under way finish (a
file is never left half-written) and hands their outcomes back.
"""
from __future__ import annotations

import concurrent.futures
import itertools
import multiprocessing
import signal
from pathlib import Path
from typing import AbstractSet, Iterator, Sequence

import cv2

from workers.orientation.detect import DetectorConfig, OrientationDetector, get_detector
from workers.common.errors import InputError
from workers.orientation.library import LibraryOptions, PathOutcome, Result, orient_path

IN_FLIGHT_PER_HELPER = 2

_worker: dict[str, object] = {}


class FilePool:
    """Use as a context manager: :meth:`outcomes` yields ``(i, outcome of files[i])`` in the order they finish (a file
    that cannot be read: a result with its error); after an interruption :meth:`stop` yields those still under way.
    ``detector``: this process's (built from ``config`` when not given)."""

    def __init__(self, files: Sequence[Path], options: LibraryOptions, known: AbstractSet[str], jobs: int,
                 config: DetectorConfig, detector: OrientationDetector | None = None) -> None:
        self.files, self.options, self.known, self.config = files, options, frozenset(known), config
        self.helpers = max(0, min(jobs, len(files)) - 1)  # no more processes than files (none for none)
        self.detector = detector
        self._pool: concurrent.futures.ProcessPoolExecutor | None = None
        self._running: dict[concurrent.futures.Future, int] = {}

    def __enter__(self) -> "FilePool":
        if self.helpers:  # its processes start with the first file handed to them
            self._pool = concurrent.futures.ProcessPoolExecutor(
                self.helpers, mp_context=multiprocessing.get_context("spawn"), initializer=_start_worker,
                initargs=(self.config, self.options, self.known))
        return self

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)

    def outcomes(self) -> Iterator[tuple[int, PathOutcome]]:
        detector = self.detector or get_detector(self.config)
        queue = iter(enumerate(self.files))
        threads = cv2.getNumThreads()
        if self.helpers:
            cv2.setNumThreads(1)  # one core each, as the helpers
        try:
            yield from self._shared(queue, detector)
        finally:
            cv2.setNumThreads(threads)

    def _shared(self, queue: Iterator[tuple[int, Path]], detector: OrientationDetector
                ) -> Iterator[tuple[int, PathOutcome]]:
        while True:
            if self._pool is not None:  # the helpers' share, handed out ahead
                for i, path in itertools.islice(queue, self.helpers * IN_FLIGHT_PER_HELPER - len(self._running)):
                    self._running[self._pool.submit(_analyse, path)] = i
            mine = next(queue, None)
            if mine is not None:  # this process's own next file
                yield mine[0], _guarded(mine[1], detector, self.options, self.known)
                ready = [future for future in self._running if future.done()]
            elif self._running:
                ready = concurrent.futures.wait(self._running, return_when=concurrent.futures.FIRST_COMPLETED)[0]
            else:
                return
            for future in ready:
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
    except InputError as exc:  # the photo's own problem (ExifTool's included): this photo fails, the others go on
        return PathOutcome(Result(path, None, "error", error=str(exc)))
