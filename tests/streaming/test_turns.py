"""Fair turns at a session's renderer: arrival order, one place per viewer, nothing drawn for a viewer that left."""
from __future__ import annotations

import threading
import time

import pytest

from workers.streaming.session import SessionError
from workers.streaming.turns import RenderTurns, ViewerLeft


class Line:
    """Viewers asking ``turns`` for a turn from their own threads; each draw waits until the test releases it."""

    def __init__(self, turns: RenderTurns) -> None:
        self.turns = turns
        self.drawn: list[str] = []
        self.outcome: dict[str, str] = {}
        self.release: dict[str, threading.Event] = {}
        self.threads: list[threading.Thread] = []

    def ask(self, viewer: str, tag: str | None = None) -> None:
        tag = tag or viewer
        self.release[tag] = threading.Event()

        def run() -> None:
            try:
                with self.turns.turn(viewer):
                    self.drawn.append(tag)
                    self.release[tag].wait(10)
                self.outcome[tag] = "drawn"
            except SessionError as exc:
                self.outcome[tag] = exc.code

        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        self.threads.append(thread)
        _until(lambda: tag in self.outcome or tag in self.drawn or self._queued(viewer))

    def _queued(self, viewer: str) -> bool:
        return viewer in self.turns._waiting

    def finish(self, tag: str) -> None:
        self.release[tag].set()
        _until(lambda: tag in self.outcome)

    def join(self) -> None:
        for event in self.release.values():
            event.set()
        for thread in self.threads:
            thread.join(10)


def _until(predicate, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.001)


def test_viewers_are_served_in_arrival_order_one_slot_at_a_time():
    line = Line(RenderTurns(slots=1))
    for viewer in "abcd":
        line.ask(viewer)
    assert line.drawn == ["a"]  # one slot: the others wait
    line.finish("a")
    line.ask("a", "a2")  # a asks again: behind b, c and d, not before them
    for tag in ["b", "c", "d", "a2"]:
        _until(lambda: line.drawn[-1] == tag)
        line.finish(tag)
    assert line.drawn == ["a", "b", "c", "d", "a2"]
    line.join()


def test_two_slots_draw_two_at_once():
    line = Line(RenderTurns(slots=2))
    for viewer in "abc":
        line.ask(viewer)
    assert line.drawn == ["a", "b"]
    line.finish("b")
    _until(lambda: line.drawn == ["a", "b", "c"])
    line.join()


def test_a_newer_request_takes_the_place_of_the_waiting_one():
    line = Line(RenderTurns(slots=1))
    line.ask("a")
    line.ask("b", "b1")
    line.ask("b", "b2")
    _until(lambda: line.outcome.get("b1") == "superseded")
    line.finish("a")
    _until(lambda: line.drawn == ["a", "b2"])
    assert line.turns.superseded == 1
    line.join()


def test_a_viewer_that_left_gets_nothing_drawn():
    turns = RenderTurns(slots=1)
    line = Line(turns)
    line.ask("a")
    for viewer in "bcd":
        line.ask(viewer)
    turns.leave("b")
    turns.leave("c")
    _until(lambda: line.outcome.get("b") == line.outcome.get("c") == "viewer_left")
    turns.leave("a")  # while its view is drawn: finished, counted
    line.finish("a")
    _until(lambda: line.drawn == ["a", "d"])
    with pytest.raises(ViewerLeft):  # a request still on its way when the viewer left
        with turns.turn("b"):
            pass
    line.join()
    assert turns.describe() == {"slots": 1, "drawing": 0, "waiting": 0, "granted": 2, "dropped_for_gone": 3,
                                "drawn_for_gone": 1, "superseded": 0}


def test_viewer_left_survives_pickling():
    import pickle

    exc = pickle.loads(pickle.dumps(ViewerLeft()))
    assert isinstance(exc, ViewerLeft) and exc.code == "viewer_left"
