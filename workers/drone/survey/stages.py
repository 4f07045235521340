"""Running a job's stages: progress with counts, tasks through the job's :class:`~workers.fanout.FanOut`, and
resuming what an earlier attempt finished.

Each stage has a share of the job's progress; while its items run it reports ``<stage> k/N`` (items done of all),
saying how many an earlier attempt had finished (``resumed``: their outputs were found in the work area and are
not run again). A stage that is one step in the job's own process records its result in the work area
(:meth:`Stages.once`). The work area carries a fingerprint of the job's input and parameters: another input or
other parameters start from scratch.

:meth:`Stages.report` gives per stage the items, how many were resumed, its wall seconds and the tasks' figures
(tasks per node, their CPU seconds, the largest worker's peak memory): ``report.json`` → ``stages``.
"""
from __future__ import annotations

import hashlib
import time
from typing import Any, Callable, Sequence, TypeVar

from workers.fanout import FanOut, stage_summary
from workers.workarea import WorkArea

T = TypeVar("T")
R = TypeVar("R")

FINGERPRINT = "fingerprint.json"


class Stages:
    """The stages of one job over its work area and fan-out; ``progress(fraction, text)`` as the job reports."""

    def __init__(self, work: WorkArea, fanout: FanOut, progress: Callable[[float, str], None], fingerprint: str):
        self.work = work
        self.fanout = fanout
        self.progress = progress
        self.records: dict[str, dict[str, Any]] = {}
        self._start_over_unless(fingerprint)

    def _start_over_unless(self, fingerprint: str) -> None:
        """Keep the work area only when it was made for this fingerprint (else clear it)."""
        found = self.work.get_json(FINGERPRINT) if self.work.exists(FINGERPRINT) else None
        self.resumed = found is not None and found.get("fingerprint") == fingerprint
        if found is not None and not self.resumed:
            self.work.clear()
        if not self.resumed:
            self.work.put_json(FINGERPRINT, {"fingerprint": fingerprint})

    def map(self, stage: str, fn: Callable[[T], R], items: Sequence[T], span: tuple[float, float],
            finished: Callable[[T], R | None] | None = None, unit: str = "",
            count: Callable[[T], int] | None = None) -> list[R]:
        """``fn`` on every item as tasks (the stage's progress from ``span[0]`` to ``span[1]``), counting ``count(item)``
        ``unit`` per item (default one); an item for which ``finished(item)`` gives a result (its output is in the
        work area) is not run again."""
        t0 = time.perf_counter()
        n = len(items)
        weights = [count(it) if count is not None else 1 for it in items]
        total = sum(weights)
        out: list[Any] = [None] * n
        todo = []
        for i, item in enumerate(items):
            found = finished(item) if finished is not None else None
            if found is not None:
                out[i] = found
            else:
                todo.append(i)
        resumed = total - sum(weights[i] for i in todo)
        done = [resumed]
        lo, hi = span
        tail = (f" {unit}" if unit else "") + (f" ({resumed} done before)" if resumed else "")

        def on_done(k: int, _: Any) -> None:
            done[0] += weights[todo[k]]
            self.progress(lo + (hi - lo) * done[0] / max(total, 1), f"{stage} {done[0]}/{total}{tail}")

        self.progress(lo + (hi - lo) * resumed / max(total, 1), f"{stage} {resumed}/{total}{tail}")
        results = self.fanout.map(stage, fn, [items[i] for i in todo], on_done)
        for i, r in zip(todo, results):
            out[i] = r
        self.records[stage] = {"items": total, "unit": unit or "items", "tasks_planned": n, "resumed": resumed,
                               "seconds": round(time.perf_counter() - t0, 3),
                               **stage_summary(self.fanout.runs.get(stage, []))}
        return out

    def found(self, name: str) -> dict[str, Any] | None:
        """A task's stored result (``<name>.json`` in the work area), None when it has not run."""
        return self.work.get_json(name + ".json") if self.work.exists(name + ".json") else None

    def once(self, stage: str, fn: Callable[[], R], at: float) -> R:
        """A step in the job's own process whose result the work area keeps: run it unless an earlier attempt did."""
        name = f"stages/{stage.replace(' ', '_')}.pkl"
        t0 = time.perf_counter()
        if self.work.exists(name):
            self.progress(at, f"{stage} (done before)")
            result = self.work.get_object(name)
            self.records[stage] = {"items": 1, "resumed": 1, "seconds": round(time.perf_counter() - t0, 3)}
            return result
        self.progress(at, stage)
        result = fn()
        self.work.put_object(name, result)
        self.records[stage] = {"items": 1, "resumed": 0, "seconds": round(time.perf_counter() - t0, 3)}
        return result

    def report(self) -> dict[str, Any]:
        """Per stage: items, resumed, seconds, and for fanned-out stages the tasks' figures (module docstring)."""
        return {"resumed_from_earlier_attempt": self.resumed, "stages": self.records}


def fingerprint(*parts: Any) -> str:
    """A SHA-256 over the parts' text (the job's parameters as JSON, its input's size and name)."""
    h = hashlib.sha256()
    for p in parts:
        h.update(str(p).encode())
        h.update(b"\0")
    return h.hexdigest()
