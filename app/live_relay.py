"""Live frame sets relayed to viewers that render in their browser.

Each API process keeps, per rig, the viewers subscribed to its live stream. A frame set reaches them two ways:
the live socket of this process publishes each set the session applied (at once), and while a rig has subscribers
here a poller asks the rig's live session actor for any newer set every ``poll_seconds`` (sets that arrived on
another replica's live socket). Either way each set is sent as the live client encoded it: the server decodes
nothing for a browser-rendering viewer, so its cost grows with frame sets, not with viewers.

A viewer that cannot keep up gets the latest set only (one-slot mailbox); when a set flagged as background was
among those it missed, the next one it gets says ``resync`` so that it fetches the server's background model.
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
from dataclasses import dataclass, field
from typing import Callable

import ray.exceptions

from workers.streaming.actor import SessionClient

log = logging.getLogger("sweepcast.rigs")
TIMING_KEYS = ("captured", "spread_ms", "stale")


@dataclass(frozen=True)
class LiveSet:
    """One applied live frame set: ``seq`` (the session's number), one JPEG per camera in rig order, whether
    it was flagged as background, and when it was taken (``timing``: ``captured``, ``spread_ms``, ``stale``, as
    :meth:`workers.streaming.session.LiveSession.timing` says)."""

    seq: int
    jpegs: list[bytes]
    background: bool
    timing: dict = field(default_factory=dict)


@dataclass(eq=False)
class Subscription:
    """One viewer's mailbox: the newest set not yet taken, and whether a background set was replaced unseen."""

    rig_id: str
    _item: LiveSet | None = None
    _ready: asyncio.Event = field(default_factory=asyncio.Event)
    missed_background: bool = False
    dropped: int = 0

    def put(self, item: LiveSet) -> None:
        if self._item is not None:
            self.dropped += 1
            self.missed_background |= self._item.background
        self._item = item
        self._ready.set()

    async def take(self) -> tuple[LiveSet, bool]:
        """The next set and whether the viewer must fetch the background model again."""
        await self._ready.wait()
        self._ready.clear()
        item, self._item = self._item, None
        resync, self.missed_background = self.missed_background, False
        return item, resync


class LiveRelay:
    """Per API process: subscriptions to rigs' live streams and their pollers (module docstring)."""

    def __init__(self, poll_seconds: float = 0.1) -> None:
        self.poll_seconds = poll_seconds
        self._subs: dict[str, set[Subscription]] = {}
        self._last: dict[str, int] = {}
        self._pollers: dict[str, asyncio.Task] = {}

    def subscribe(self, rig_id: str, client: Callable[[], SessionClient]) -> Subscription:
        """A new subscription to ``rig_id``'s live sets; ``client`` makes the session client its poller uses."""
        sub = Subscription(rig_id)
        self._subs.setdefault(rig_id, set()).add(sub)
        if rig_id not in self._pollers or self._pollers[rig_id].done():
            self._pollers[rig_id] = asyncio.create_task(self._poll(rig_id, client()))
        return sub

    async def unsubscribe(self, sub: Subscription) -> None:
        subs = self._subs.get(sub.rig_id, set())
        subs.discard(sub)
        if not subs:
            self._subs.pop(sub.rig_id, None)
            self._last.pop(sub.rig_id, None)  # a later viewer starts from whatever the session shows then
            task = self._pollers.pop(sub.rig_id, None)
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task

    def publish(self, rig_id: str, item: LiveSet) -> None:
        """Hand ``item`` to every subscriber of ``rig_id`` unless a newer set went out already."""
        if item.seq <= self._last.get(rig_id, 0):
            return
        self._last[rig_id] = item.seq
        for sub in self._subs.get(rig_id, ()):
            sub.put(item)

    def subscribers(self, rig_id: str) -> int:
        return len(self._subs.get(rig_id, ()))

    async def _poll(self, rig_id: str, client: SessionClient) -> None:
        while self._subs.get(rig_id):
            try:
                reply = await client.frame_set_after(self._last.get(rig_id, 0))
            except ray.exceptions.RayError as exc:
                log.warning("polling the live session of rig %s failed: %s", rig_id, exc)
                reply = None
            if reply is not None:
                self.publish(rig_id, LiveSet(reply["seq"], reply["jpegs"], reply["background"],
                                             {k: reply.get(k) for k in TIMING_KEYS}))
            await asyncio.sleep(self.poll_seconds)
