"""One trial of a reader design (``benchmarks/live_ingest.py``, section ``readers``), in a fresh process so that its
peak memory is its own: ``python -m benchmarks._readers_trial DESIGN SECONDS FPS WIDTH HEIGHT URL...`` prints one
JSON line of what it measured.

``thread``: one :class:`app.capture.readers.CameraReader` thread per camera, as ``sweepcast live`` runs them;
``process``: one reader process per camera handing its frames over through shared memory
(:mod:`benchmarks._reader_process`); ``thread-bgr``: reader threads that convert to BGR as they decode. Either way the frames land in one mailbox per camera and the capture side's
:class:`app.capture.assembly.SetAssembler` takes sets from them as ``sweepcast live`` does (woken by each frame,
tolerance half a frame period), then takes each frame's pixels as BGR (what the uplink's JPEG encoding reads;
the encoding itself, the same for both designs, is left out). Measured over SECONDS, from 3 s after the first set:
frames delivered per camera, sets, the CPU of this process and of its reader processes, the age of the newest frame
of each camera and of the set's instant when a set has been taken, and peak resident memory.
"""
from __future__ import annotations

import json
import os
import sys
import threading
import time
from typing import Any, Callable

import numpy as np

from app.capture.assembly import SetAssembler
from app.capture.clocks import CaptureClock
from app.capture.mailbox import FrameMailbox
from app.capture.readers import CameraReader
from app.capture.settings import CaptureSettings
from app.capture.sources import Source
from benchmarks._reader_process import ProcessReader
from harness.proc import cpu_seconds, machine_busy_seconds, status_mb

DESIGNS = ("thread", "process", "thread-bgr")
"""``thread-bgr``: reader threads that convert each frame to BGR as they decode it (where a reader process must)
instead of when a set takes it (what ``sweepcast live``'s mailboxes do): tells the gain of converting early from
the gain of processes."""
WARMUP_S = 3.0
FIRST_SET_TIMEOUT_S = 60.0


class NotifyingMailbox(FrameMailbox):
    """A mailbox that wakes the assembler when a frame arrives (as ``sweepcast live``'s do); ``early``: it converts
    each frame to BGR first, on the reader's thread (``thread-bgr``)."""

    def __init__(self, keep: int, arrived: threading.Event, early: bool = False) -> None:
        super().__init__(keep)
        self._arrived = arrived
        self._early = early

    def put(self, frame) -> None:
        if self._early:
            frame.bgr()
        super().put(frame)
        self._arrived.set()


def start_readers(design: str, urls: list[str], size: tuple[int, int], mailboxes: list[FrameMailbox],
                  settings: CaptureSettings) -> tuple[list[int], Callable[[], None], Callable[[], int]]:
    """Start one reader per camera of ``design``: (the reader processes' pids, a function that stops them all, one
    that counts the frames overwritten in shared memory before they were copied)."""
    if design in ("thread", "thread-bgr"):
        readers = [CameraReader(Source(i, f"camera{i}", "rtsp", url), size, CaptureClock(), box, settings,
                                report=lambda message: print(message, file=sys.stderr, flush=True))
                   for i, (url, box) in enumerate(zip(urls, mailboxes))]
        for reader in readers:
            reader.start()

        def stop_threads() -> None:
            for reader in readers:
                reader.stop_soon()
            for reader in readers:
                reader.stop()
        return [], stop_threads, lambda: 0
    children = [ProcessReader(i, url, size, box) for i, (url, box) in enumerate(zip(urls, mailboxes))]

    def stop_processes() -> None:
        for child in children:
            child.stop()
    return [c.pid for c in children], stop_processes, lambda: sum(c.torn for c in children)


def trial(design: str, seconds: float, fps: float, size: tuple[int, int], urls: list[str]) -> dict[str, Any]:
    """Run ``design``'s readers on ``urls`` and measure them (module docstring)."""
    settings = CaptureSettings()
    arrived = threading.Event()
    mailboxes = [NotifyingMailbox(settings.keep_frames, arrived, early=design == "thread-bgr") for _ in urls]
    assembler = SetAssembler(mailboxes, 0.5 / fps, settings.missing_seconds)
    pids, stop, torn = start_readers(design, urls, size, mailboxes, settings)
    try:
        deadline = time.monotonic() + FIRST_SET_TIMEOUT_S
        while _take(assembler, arrived) is None:
            if time.monotonic() > deadline:
                raise SystemExit(f"{design}: no frame set within {FIRST_SET_TIMEOUT_S:g} s")
        warm_until = time.monotonic() + WARMUP_S
        while time.monotonic() < warm_until:
            _take(assembler, arrived)
        received0 = [box.received for box in mailboxes]
        sets0, torn0 = assembler.sets, torn()
        own0, children0 = cpu_seconds(os.getpid()), [cpu_seconds(p) for p in pids]
        busy0, t0, load0 = machine_busy_seconds(), time.monotonic(), os.getloadavg()[0]
        newest_ages, set_ages = [], []
        while time.monotonic() - t0 < seconds:
            frame_set = _take(assembler, arrived)
            if frame_set is None:
                continue
            taken = time.time()
            set_ages.append(taken - frame_set.instant)
            newest_ages += [taken - box.newest().capture for box in mailboxes]
        wall = time.monotonic() - t0
        own, children = cpu_seconds(os.getpid()) - own0, [cpu_seconds(p) - c for p, c in zip(pids, children0)]
        per_camera = [(box.received - r) / wall for box, r in zip(mailboxes, received0)]
        out = {
            "design": design, "cameras": len(urls), "size": f"{size[0]}x{size[1]}", "fps": fps, "seconds": wall,
            "fps_per_camera": per_camera, "frames_per_s": sum(per_camera),
            "sets_per_s": (assembler.sets - sets0) / wall,
            "torn": torn() - torn0,
            "parent_cores": own / wall, "children_cores": sum(children) / wall, "cores": (own + sum(children)) / wall,
            "newest_age_p50_ms": _percentile(newest_ages, 50), "newest_age_p95_ms": _percentile(newest_ages, 95),
            "set_age_p50_ms": _percentile(set_ages, 50), "set_age_p95_ms": _percentile(set_ages, 95),
            "parent_peak_rss_mb": status_mb(os.getpid(), "VmHWM"),
            "child_peak_rss_mb": [status_mb(p, "VmHWM") for p in pids],
            "machine_busy_cores": (machine_busy_seconds() - busy0) / wall,
            "load_average_start_end": [round(load0, 2), round(os.getloadavg()[0], 2)],
        }
        out["children_peak_rss_mb"] = sum(out["child_peak_rss_mb"])
        return out
    finally:
        stop()


def _take(assembler: SetAssembler, arrived: threading.Event):
    """The assembler's next set with each frame's pixels taken as BGR (``sweepcast live``'s loop without the
    uplink), or None."""
    arrived.wait(0.05)
    arrived.clear()
    frame_set = assembler.next_set()
    if frame_set is not None:
        for frame in frame_set.frames:
            if frame is not None:
                frame.bgr()
    return frame_set


def _percentile(seconds: list[float], q: float) -> float | None:
    return float(np.percentile(seconds, q)) * 1e3 if seconds else None


def main(argv: list[str]) -> None:
    design, seconds, fps, width, height, *urls = argv
    if design not in DESIGNS:
        raise SystemExit(f"design must be one of {', '.join(DESIGNS)}, not {design!r}")
    print(json.dumps(trial(design, float(seconds), float(fps), (int(width), int(height)), urls)), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
