"""How long the rest of a run will take, from its pace so far (the progress of batch jobs and of the CLI)."""
from __future__ import annotations

import math
import time
from typing import Callable


class Pace:
    """The time left for ``todo`` items from the pace of those finished so far in this run: the time since it started
    over the items finished. Items carried over from an earlier run took no time now and are not part of ``todo``."""

    def __init__(self, todo: int, clock: Callable[[], float] = time.monotonic) -> None:
        self.todo = todo
        self.done = 0
        self._clock = clock
        self._start = clock()

    def add(self, items: int = 1) -> None:
        """Count ``items`` more as finished."""
        self.done += items

    def skip(self, items: int = 1) -> None:
        """Count ``items`` as needing no work after all (found already done): no longer part of ``todo``."""
        self.todo -= items

    def seconds_left(self) -> float | None:
        """Seconds until every item is finished at the pace so far; None before the first one finished."""
        if self.done <= 0:
            return None
        return max(0.0, (self._clock() - self._start) / self.done * (self.todo - self.done))


def describe_seconds(seconds: float) -> str:
    """A duration as people say it, to the precision that matters: ``8 s``, ``3 min 10 s``, ``2 h 05 min``."""
    whole = max(0, math.ceil(seconds))
    if whole < 60:
        return f"{whole} s"
    minutes, secs = divmod(whole, 60)
    if minutes < 60:
        return f"{minutes} min {secs:02d} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes:02d} min"
