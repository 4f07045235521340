"""Fair turns at a session's renderer for its viewers.

A session draws at most ``slots`` views at once; the viewers waiting for one are served in the order they
asked (first come, first served), and each viewer holds at most one place in that line: a viewer asks for its
next view only after its previous one came back, so the line is a round robin, and a viewer that just joined
waits for at most one view of each viewer ahead of it. A newer request of a viewer that still waits takes its
place (latest wins; the older one is answered ``superseded``). A viewer that left loses its place at once:
nothing is drawn for it after :meth:`RenderTurns.leave`, and the counters say what was dropped.

Plain threads (the session actor serves each call on its own thread); no Ray here.
"""
from __future__ import annotations

import contextlib
import threading
from collections import OrderedDict, deque
from dataclasses import dataclass
from typing import Iterator

from .session import SessionError

GONE_KEPT = 4096
"""Viewers remembered as gone (ids are unique per socket): a request of theirs still on its way is dropped."""


class ViewerLeft(SessionError):
    """The viewer left before its view was drawn: nothing was drawn for it."""

    def __init__(self, detail: str = "the viewer left before its view was drawn") -> None:
        super().__init__("viewer_left", detail)

    def __reduce__(self) -> tuple:
        return (type(self), (self.detail,))


@dataclass(eq=False)
class _Place:
    viewer: str
    cancelled: SessionError | None = None


class RenderTurns:
    """Grants turns to draw, ``slots`` at a time, in arrival order, one place per viewer (module docstring)."""

    def __init__(self, slots: int = 1) -> None:
        if slots < 1:
            raise ValueError(f"slots must be at least 1; got {slots}")
        self.slots = slots
        self._cond = threading.Condition()
        self._line: deque[_Place] = deque()
        self._waiting: dict[str, _Place] = {}
        self._gone: OrderedDict[str, None] = OrderedDict()
        self.drawing = 0
        self.granted = 0
        """Turns granted since the start."""
        self.dropped_for_gone = 0
        """Requests dropped undrawn because their viewer had left (waiting in line, or arriving after it left)."""
        self.drawn_for_gone = 0
        """Views finished after their viewer had left (it left while the view was being drawn): at most one per
        viewer, drawn because it had started; none is ever started for a viewer that left."""
        self.superseded = 0
        """Requests replaced in line by a newer one of the same viewer."""

    @contextlib.contextmanager
    def turn(self, viewer: str) -> Iterator[int]:
        """Wait for ``viewer``'s turn and hold it while the body draws; yields the turn's number (1, 2, ... in the
        order granted). Raises :class:`ViewerLeft` when the viewer
        left (before or while it waited) and SessionError ``superseded`` when a newer request took its place."""
        with self._cond:
            if viewer in self._gone:
                self.dropped_for_gone += 1
                raise ViewerLeft()
            older = self._waiting.get(viewer)
            if older is not None:
                self.superseded += 1
                self._cancel(older, SessionError("superseded", "a newer viewpoint of this viewer took its place"))
            place = _Place(viewer)
            self._line.append(place)
            self._waiting[viewer] = place
            while place.cancelled is None and not (self._line[0] is place and self.drawing < self.slots):
                self._cond.wait()
            if place.cancelled is not None:
                raise place.cancelled
            self._line.popleft()
            del self._waiting[viewer]
            self.drawing += 1
            self.granted += 1
            number = self.granted
            self._cond.notify_all()  # the next in line may have a free slot too
        try:
            yield number
        finally:
            with self._cond:
                self.drawing -= 1
                if viewer in self._gone:
                    self.drawn_for_gone += 1
                self._cond.notify_all()

    def leave(self, viewer: str) -> None:
        """``viewer`` left: drop its waiting request (answered :class:`ViewerLeft`) and any that arrives later."""
        with self._cond:
            self._gone[viewer] = None
            while len(self._gone) > GONE_KEPT:
                self._gone.popitem(last=False)
            place = self._waiting.get(viewer)
            if place is not None:
                self.dropped_for_gone += 1
                self._cancel(place, ViewerLeft())

    def describe(self) -> dict[str, int]:
        with self._cond:
            return {"slots": self.slots, "drawing": self.drawing, "waiting": len(self._line), "granted": self.granted,
                    "dropped_for_gone": self.dropped_for_gone, "drawn_for_gone": self.drawn_for_gone,
                    "superseded": self.superseded}

    def _cancel(self, place: _Place, why: SessionError) -> None:
        """Take ``place`` out of the line (lock held) and wake its waiter with ``why``."""
        place.cancelled = why
        self._line.remove(place)
        del self._waiting[place.viewer]
        self._cond.notify_all()
