"""The files of a library analysed by this process or by a pool of helper processes, each result handed back as it
comes.

With ``jobs`` 1 this process analyses the files itself. With ``jobs`` N > 1, N helpers (forked from a server process
that has imported the engine once, or spawned where the platform has no fork server: nothing of this process is
shared with them but what is passed) analyse files at once, each running
:func:`workers.orientation.library.orient_path` on one file at a time with its own detector, built once, and OpenCV
on one thread (the processes share the cores out, one each), while this process only hands files out and collects
what they decided: a helper that finishes a file gets the next at once, where a process that also analysed would leave
its helpers waiting while it read a slow text photo (seconds). The helpers are started, and handed their first files,
as the pool is entered. At most ``IN_FLIGHT_PER_HELPER`` files per helper are handed out ahead, so that a run that is
stopped has little under way: :meth:`FilePool.stop` lets the files under way finish (a file is never left
half-written) and hands their outcomes back.
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
PRELOAD = ("workers.orientation.pool", "onnxruntime")
"""What the helpers' fork server imports once (:func:`_context`): the engine, and onnxruntime (its networks')."""

_worker: dict[str, object] = {}


class FilePool:
    """Use as a context manager: :meth:`outcomes` yields ``(i, outcome of files[i])`` in the order they finish (a file
    that cannot be read: a result with its error); after an interruption :meth:`stop` yields those still under way.
    ``detector``: this process's, for ``jobs`` 1 (built from ``config`` when not given); :attr:`helpers` says how many
    helper processes analyse the files (0: this process does)."""

    def __init__(self, files: Sequence[Path], options: LibraryOptions, known: AbstractSet[str], jobs: int,
                 config: DetectorConfig, detector: OrientationDetector | None = None) -> None:
        self.files, self.options, self.known, self.config = files, options, frozenset(known), config
        processes = min(jobs, len(files))  # no more processes than files
        self.helpers = processes if processes > 1 else 0
        self.detector = detector
        self._pool: concurrent.futures.ProcessPoolExecutor | None = None
        self._running: dict[concurrent.futures.Future, int] = {}
        self._queue: Iterator[tuple[int, Path]] = iter(enumerate(self.files))

    def __enter__(self) -> "FilePool":
        if self.helpers:  # its processes start with the first files handed to them: now
            self._pool = concurrent.futures.ProcessPoolExecutor(
                self.helpers, mp_context=_context(), initializer=_start_worker,
                initargs=(self.config, self.options, self.known))
            self._hand_out()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)

    def outcomes(self) -> Iterator[tuple[int, PathOutcome]]:
        """The outcomes as they come."""
        if self._pool is None:
            detector = self.detector or get_detector(self.config)
            for i, path in self._queue:
                yield i, _guarded(path, detector, self.options, self.known)
            return
        while self._running:
            ready = concurrent.futures.wait(self._running, return_when=concurrent.futures.FIRST_COMPLETED)[0]
            for future in ready:
                i = self._running.pop(future)
                self._hand_out()  # the helper that finished has its next file before this one is reported
                yield i, future.result()

    def _hand_out(self) -> None:
        """The helpers' share, handed out ahead (``IN_FLIGHT_PER_HELPER`` files each)."""
        assert self._pool is not None
        for i, path in itertools.islice(self._queue, self.helpers * IN_FLIGHT_PER_HELPER - len(self._running)):
            self._running[self._pool.submit(_analyse, path)] = i

    def stop(self) -> Iterator[tuple[int, PathOutcome]]:
        """Start no other file; the outcomes of those under way as they finish."""
        for future in list(self._running):
            if future.cancel():
                del self._running[future]
        for future in concurrent.futures.as_completed(list(self._running)):
            yield self._running.pop(future), future.result()


def _context() -> multiprocessing.context.BaseContext:
    """How helpers start: forked from a server process that has imported the engine's modules once (``forkserver``,
    where the platform has it), which saves each helper the imports (about 0.7 s of CPU of the ~1.8 s a helper takes
    to start); else spawned. Neither shares anything of this process with them."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(list(PRELOAD))
    return context


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
