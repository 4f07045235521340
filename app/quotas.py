"""Per-key quotas: bytes stored, jobs queued or running, viewer sessions, uploads per minute.

Limits come from the settings (``quota_*``), overridden per key (a managed key's ``quota``). Admin keys have no
limits unless their key sets some. Stored bytes and active jobs are read from the job table (shared by every
replica); viewer sessions and the upload rate are counted by each API replica for its own connections.
"""
from __future__ import annotations

import asyncio
import collections
import math
import time
from dataclasses import dataclass
from typing import Any

from app.errors import ApiError
from app.jobstore import JobStore
from app.keys import Principal

QUOTA_FIELDS = ("stored_bytes", "active_jobs", "viewer_sessions", "uploads_per_minute")
RATE_WINDOW_S = 60.0
ACTIVE_JOBS_RETRY_S = 30
"""Retry-After when a key has its most jobs queued or running: about how long a small job takes."""


@dataclass(frozen=True)
class QuotaLimits:
    stored_bytes: int | None
    active_jobs: int | None
    viewer_sessions: int | None
    uploads_per_minute: int | None

    def as_dict(self) -> dict[str, int | None]:
        return {f: getattr(self, f) for f in QUOTA_FIELDS}


UNLIMITED = QuotaLimits(None, None, None, None)


class Quotas:
    """One API replica's quota keeper."""

    def __init__(self, defaults: QuotaLimits, jobs: JobStore) -> None:
        self.defaults = defaults
        self.jobs = jobs
        self._uploads: dict[str, collections.deque[float]] = collections.defaultdict(collections.deque)
        self._viewers: collections.Counter[str] = collections.Counter()

    def limits(self, who: Principal) -> QuotaLimits:
        """The key's limits: its overrides over the defaults (admin: none beyond its overrides)."""
        base = UNLIMITED if who.is_admin else self.defaults
        over = who.quota or {}
        return QuotaLimits(**{f: int(over[f]) if over.get(f) is not None else getattr(base, f) for f in QUOTA_FIELDS})

    def take_upload(self, who: Principal, now: float | None = None) -> ApiError | None:
        """Count one upload of ``who``; the 429 to answer (with Retry-After) when it is past its rate."""
        limit = self.limits(who).uploads_per_minute
        if limit is None:
            return None
        now = time.monotonic() if now is None else now
        window = self._uploads[who.id]
        while window and window[0] <= now - RATE_WINDOW_S:
            window.popleft()
        if len(window) >= limit:
            retry = max(1, math.ceil(window[0] + RATE_WINDOW_S - now))
            return ApiError(429, f"this key sent {len(window)} uploads in the last minute, its limit; retry in "
                                 f"{retry} s", "upload_rate_exceeded", headers={"Retry-After": str(retry)})
        window.append(now)
        return None

    async def check_new_job(self, who: Principal, incoming_bytes: int) -> None:
        """Before a job's inputs are stored: 429 (Retry-After) when the key has its most jobs queued or running,
        507 when the inputs would take it past its stored bytes."""
        limits = self.limits(who)
        if limits.stored_bytes is None and limits.active_jobs is None:
            return
        stored, active = await asyncio.to_thread(self.jobs.usage, who.id)
        if limits.active_jobs is not None and active >= limits.active_jobs:
            raise ApiError(429, f"this key has {active} jobs queued or running, its limit; wait for one to finish",
                           "active_jobs_exceeded", headers={"Retry-After": str(ACTIVE_JOBS_RETRY_S)})
        if limits.stored_bytes is not None and stored + incoming_bytes > limits.stored_bytes:
            raise ApiError(507, f"this key stores {stored:,} bytes; {incoming_bytes:,} more would pass its limit of "
                                f"{limits.stored_bytes:,}: delete jobs or recordings it no longer needs",
                           "storage_quota_exceeded")

    def open_viewer(self, who: Principal) -> ApiError | None:
        """Count one more open viewer socket of ``who``; the refusal to send when it has its most open (then
        nothing is counted). Every counted one is given back with :meth:`close_viewer`."""
        limit = self.limits(who).viewer_sessions
        if limit is not None and self._viewers[who.id] >= limit:
            return ApiError(429, f"this key has {self._viewers[who.id]} viewer sessions open on this server, its "
                                 "limit; close one", "viewer_sessions_exceeded", headers={"Retry-After": "5"})
        self._viewers[who.id] += 1
        return None

    def close_viewer(self, who: Principal) -> None:
        self._viewers[who.id] -= 1
        if self._viewers[who.id] <= 0:
            del self._viewers[who.id]

    async def usage(self, who: Principal) -> dict[str, Any]:
        """What the key uses now (its jobs from the table; viewers and uploads on this replica)."""
        stored, active = await asyncio.to_thread(self.jobs.usage, who.id)
        window = self._uploads.get(who.id, ())
        recent = sum(1 for t in window if t > time.monotonic() - RATE_WINDOW_S)
        return {"stored_bytes": stored, "active_jobs": active, "viewer_sessions": self._viewers.get(who.id, 0),
                "uploads_per_minute": recent}
