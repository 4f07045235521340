"""The viewer's quality levels: what each sets of the renderer's options, and which one a session draws.

A viewer asks for a ``quality`` (:class:`workers.streaming.params.Viewpoint`): "best", "fast" or "auto" (the
default). Each level is a preset of the options that decide the depth (:data:`LEVELS`); an option a client sets
itself wins over its level's (the level then reads "custom"). Measured on Middlebury and the demo studio
(benchmarks/RESULTS.md, section sweep, "The viewer's quality levels"):

- "best": semi-global aggregation with the occlusion fill (visibility-aware colour at the filled pixels): the
  highest PSNR on Middlebury Teddy and Art (from two views above OpenCV SGBM + DIBR) and on the demo studio, and
  the least smear at occluding edges; below "fast" on templeSparseRing's wide ring (its cross-view check rejects
  about 40 % of the object there: mismatches, which the background's depth does not mend) and, by a fraction of a
  dB, on a textureless occluder. The fill's cross-view check and its fine-level cost volume cost about three times
  the depth search of "fast".
- "fast": semi-global aggregation, the depth kept as searched: 0.6-3 dB above the window aggregation the viewer
  used before on the real sets, at about its speed.

"auto" draws "best" where the session holds the viewer's target rate with it, else "fast"
(:class:`QualityChooser`): the measured render times at that view size decide (fast's first, so the first frame
comes soonest), and a level found too slow is tried again after a while (the load may have gone). The browser's
renderer makes the same choice with its own render times (app/static/viewer.js).
"""
from __future__ import annotations

import statistics
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable, Literal

Level = Literal["best", "fast"]
Quality = Literal["auto", "best", "fast"]

LEVELS: dict[str, dict[str, str]] = {
    "best": {"aggregation": "sgm", "occlusions": "fill"},
    "fast": {"aggregation": "sgm", "occlusions": "keep"},
}
"""Per level, the renderer options (:class:`workers.sweep.renderer.RenderOptions` fields) it sets."""

LEVEL_FIELDS = ("aggregation", "occlusions")
"""The options a level decides; a client's own value for one of them makes the level "custom"."""

CUSTOM = "custom"


def level_options(level: str, given: dict[str, object]) -> tuple[dict[str, object], str]:
    """The options of ``level`` ("best" or "fast") under the client's own ``given`` values of
    :data:`LEVEL_FIELDS` (None: not given), and the name of what runs: the level, or "custom" when a given value
    differs from the level's."""
    preset = LEVELS[level]
    options = {k: preset[k] if given.get(k) is None else given[k] for k in LEVEL_FIELDS}
    return options, level if options == preset else CUSTOM


@dataclass
class _Record:
    """The last render times (ms) of each level at one view shape, and since when "best" counts as too slow."""

    fast: deque = field(default_factory=lambda: deque(maxlen=QualityChooser.SAMPLES))
    best: deque = field(default_factory=lambda: deque(maxlen=QualityChooser.SAMPLES))
    slow_since: float | None = None


class QualityChooser:
    """The "auto" choice of one session, per view shape (width, height, planes): "fast" first (the first frame
    comes soonest); "best" once the median of fast's last :attr:`SAMPLES` times there is at most half the frame
    budget (1000 / ``target_fps`` ms: best costs two to four times fast on a CPU, so it could not hold otherwise),
    and as long as best's own median (of at least two times, or one over four budgets) stays within the budget;
    after best missed it, fast for ``retry_s`` seconds, then best is tried again (the load may have gone).
    Thread-safe enough for the session's draws: a lost update only delays a switch by a frame."""

    SAMPLES = 3

    def __init__(self, target_fps: float, retry_s: float = 60.0, clock: Callable[[], float] = time.monotonic) -> None:
        if not target_fps > 0:
            raise ValueError(f"target_fps must be > 0, got {target_fps}")
        self.budget_ms = 1000.0 / target_fps
        self.retry_s = retry_s
        self._clock = clock
        self._shapes: dict[tuple[int, int, int], _Record] = {}

    def choose(self, shape: tuple[int, int, int]) -> Level:
        """The level to draw a view of ``shape`` (width, height, planes) at."""
        record = self._shapes.get(shape)
        if record is None or not record.fast:
            return "fast"
        if record.slow_since is not None:
            if self._clock() - record.slow_since < self.retry_s:
                return "fast"
            record.slow_since = None  # try again; its next times decide
            record.best.clear()
        return "best" if statistics.median(record.fast) <= self.budget_ms / 2 else "fast"

    def record(self, shape: tuple[int, int, int], level: str, ms: float) -> None:
        """A render of ``shape`` at ``level`` took ``ms``."""
        if level not in LEVELS:
            return
        record = self._shapes.setdefault(shape, _Record())
        times = record.best if level == "best" else record.fast
        times.append(ms)
        # one time of best decides only when far over (a size's first render also allocates its buffers)
        enough = len(times) >= 2 or ms > 4 * self.budget_ms
        if level == "best" and enough and statistics.median(times) > self.budget_ms:
            record.slow_since = self._clock()
        while len(self._shapes) > 64:  # a viewer resizing through many sizes: forget the oldest
            del self._shapes[next(iter(self._shapes))]
