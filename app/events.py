"""In-process fan-out of job events to WebSocket subscribers."""
from __future__ import annotations

import asyncio
from collections import defaultdict
from typing import Any


class EventHub:
    """Each subscriber gets its own queue; a slow subscriber loses old progress, never the final state."""

    def __init__(self, queue_size: int = 256) -> None:
        self._subscribers: dict[str, set[asyncio.Queue]] = defaultdict(set)
        self._queue_size = queue_size

    def subscribe(self, job_id: str) -> asyncio.Queue:
        queue: asyncio.Queue = asyncio.Queue(self._queue_size)
        self._subscribers[job_id].add(queue)
        return queue

    def unsubscribe(self, job_id: str, queue: asyncio.Queue) -> None:
        subs = self._subscribers.get(job_id)
        if subs is not None:
            subs.discard(queue)
            if not subs:
                del self._subscribers[job_id]

    def publish(self, job_id: str, event: dict[str, Any]) -> None:
        for queue in list(self._subscribers.get(job_id, ())):
            if queue.full():
                try:
                    queue.get_nowait()  # drop the oldest progress event
                except asyncio.QueueEmpty:
                    pass
            queue.put_nowait(event)
