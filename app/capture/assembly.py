"""Frame sets by capture time: one frame per camera, all taken within the tolerance of each other.

A set's *spread* is its latest capture time minus its earliest (over the cameras present). The assembler looks at
each camera's newest frames (:class:`~app.capture.mailbox.FrameMailbox`) and tries instants newest first: for an
instant T every present camera gives its frame nearest T, and the first T whose frames spread over at most the
tolerance (default half a frame period) is the set, provided it is later than the previous set's instant by more
than the tolerance (a set is never sent twice). A camera whose frame for T has not arrived yet makes T fail: an
older, complete instant is sent meanwhile, and T once it is complete.

A camera that has sent nothing for ``missing_seconds`` is *missing*: sets go on without waiting for it, carrying its
last frame (or a black one, if it never sent any) marked stale, and the service leaves a stale camera out of what it
renders. Why stale rather than holding every set until the camera is back: a rig of ten cameras loses one now and
then, and holding would freeze the whole live view for as long (a camera's reboot: a minute); without the stale
camera the sweep still sees the scene from the others, at one instant. Until ``missing_seconds`` have passed the
sets wait for it (a late frame is not a lost camera).
"""
from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from typing import Callable, Sequence

import cv2
import numpy as np

from .mailbox import Frame, FrameMailbox


@dataclass(frozen=True)
class FrameSet:
    """One set, rig order: ``frames[i]`` (None: camera i never sent a frame), ``stale[i]`` (camera i is missing:
    its frame is not of this instant), ``instant`` (median capture time of the fresh frames, s since the epoch) and
    ``spread`` (s, over the fresh frames)."""

    frames: list[Frame | None]
    stale: list[bool]
    instant: float
    spread: float

    @property
    def captured(self) -> list[float | None]:
        """Each frame's capture time (s since the epoch), None where there is no frame."""
        return [f.capture if f is not None else None for f in self.frames]


class SetAssembler:
    """Builds :class:`FrameSet` s from the cameras' mailboxes (see the module docstring). ``tolerance``: the largest
    spread (s); ``missing_seconds``: how long a silent camera is waited for; ``clock``: the arrival clock."""

    def __init__(self, mailboxes: Sequence[FrameMailbox], tolerance: float, missing_seconds: float,
                 clock: Callable[[], float] = time.time) -> None:
        self.mailboxes = list(mailboxes)
        self.tolerance = tolerance
        self.missing_seconds = missing_seconds
        self.clock = clock
        self.started = clock()
        self.last_instant = float("-inf")
        self.best_failed_spread: float | None = None
        """The smallest spread found the last time no instant was within the tolerance (None once one was): what
        the status line says when sets stop."""
        self.sets = 0
        self.used = [0] * len(self.mailboxes)

    def missing(self) -> list[bool]:
        """Per camera: silent for ``missing_seconds`` (or never heard from, that long after the start)."""
        now = self.clock()
        out = []
        for box in self.mailboxes:
            newest = box.newest()
            last = newest.arrival if newest is not None else self.started
            out.append(now - last > self.missing_seconds)
        return out

    def next_set(self) -> FrameSet | None:
        """The newest complete set not sent yet, or None (wait: a camera's frame is still to come, or none is within
        the tolerance, or fewer than two cameras are present)."""
        missing = self.missing()
        present = [i for i, m in enumerate(missing) if not m]
        if len(present) < 2:
            return None
        recent = {i: self.mailboxes[i].recent() for i in present}
        if any(not recent[i] for i in present):
            return None
        keep = max(len(r) for r in recent.values())
        captures = np.full((len(present), keep), np.inf)  # (camera present, frame kept): capture times, s
        for row, i in enumerate(present):
            captures[row, :len(recent[i])] = [f.capture for f in recent[i]]
        candidates = np.unique(captures[np.isfinite(captures) & (captures > self.last_instant + self.tolerance)])[::-1]
        if not len(candidates):
            return None
        # for each candidate instant (newest first), each camera's frame nearest it: (camera, candidate)
        nearest = np.abs(captures[:, :, None] - candidates[None, None, :]).argmin(axis=1)
        times = np.take_along_axis(captures, nearest, axis=1)
        spreads = times.max(axis=0) - times.min(axis=0)
        good = (spreads <= self.tolerance) & (times.min(axis=0) > self.last_instant + self.tolerance / 2)
        if not good.any():
            self.best_failed_spread = float(spreads.min())
            return None
        k = int(np.argmax(good))  # the newest good instant
        picked = {i: recent[i][int(nearest[row, k])] for row, i in enumerate(present)}
        return self._made(picked, missing, times[:, k].tolist(), float(spreads[k]))

    def _made(self, picked: dict[int, Frame], missing: list[bool], times: list[float], spread: float) -> FrameSet:
        frames: list[Frame | None] = [picked.get(i) or self.mailboxes[i].newest() for i in range(len(self.mailboxes))]
        instant = statistics.median(times)
        self.last_instant = instant
        self.best_failed_spread = None
        self.sets += 1
        for i in picked:
            self.used[i] += 1
        return FrameSet(frames, list(missing), instant, spread)


def black_jpeg(size: tuple[int, int], quality: int = 50) -> bytes:
    """A black JPEG of ``size`` (width, height): the stand-in for a stale camera that never sent a frame."""
    return cv2.imencode(".jpg", np.zeros((size[1], size[0], 3), np.uint8), [cv2.IMWRITE_JPEG_QUALITY, quality])[1].tobytes()
