"""The bound on what a synchronous route may compute in the API process, and on how much of it runs at once.

A synchronous route (``POST /v1/depth/filter``, ``/v1/depth/synthesize``) works in the API process itself, on
the compute threads every other route shares. Before any pixel is decoded the route estimates the request's cost
from the image headers and its parameters (:mod:`workers.depth.cost`: CPU seconds and peak memory), and
:class:`SyncWorkGate`:

- refuses a request whose estimate is over ``sync_max_cpu_seconds`` or ``sync_max_memory_mb`` with 413 and a JSON
  body that says what it would cost and where to send it instead (the job route);
- admits the others while the estimated memory of the requests in flight stays within ``sync_memory_budget_mb``;
  a request that finds no room within ``sync_wait_seconds`` gets 503 with ``Retry-After``.

``POST /v1/face-models/{id}/transform`` shares the budget (admission only: its upload limit keeps one request
under ~800 MB, :func:`workers.faces.mesh.parse_estimate`): parsing a large mesh holds ~12 bytes per uploaded byte
before the mesh is found to be of another topology.

So the API process holds at most the budget for this work beside its own memory, and one request holds the
compute threads for at most about the CPU limit.
"""
from __future__ import annotations

import asyncio
import math
import os
from contextlib import asynccontextmanager
from dataclasses import dataclass
from typing import AsyncIterator, Awaitable, Callable, TypeVar

from app.errors import ApiError
from app.settings import MiB, Settings
from workers.common.work import WorkEstimate

R = TypeVar("R")
BUSY_RESPONSE = {"description": "other large requests hold the service's SWEEPCAST_SYNC_MEMORY_BUDGET_MB for "
                                "longer than SWEEPCAST_SYNC_WAIT_SECONDS: retry after `Retry-After` seconds"}
"""The 503 of the routes whose work goes through :meth:`SyncWorkGate.run` (their OpenAPI ``responses``)."""


@dataclass(frozen=True)
class SyncWorkLimits:
    """max_cpu_seconds / max_memory_bytes: one request's estimate; budget_bytes: the estimated memory of all
    requests in flight; wait_seconds: how long a request waits for room in the budget."""

    max_cpu_seconds: float
    max_memory_bytes: int
    budget_bytes: int
    wait_seconds: float

    @classmethod
    def from_settings(cls, s: Settings) -> "SyncWorkLimits":
        return cls(s.sync_max_cpu_seconds, int(s.sync_max_memory_mb * MiB), int(s.sync_memory_budget_mb * MiB),
                   s.sync_wait_seconds)


def _mb(n: int) -> str:
    return f"{n / MiB:,.0f} MB"


class SyncWorkGate:
    """Checks and admits the synchronous routes' work (module docstring). One per API process."""

    def __init__(self, limits: SyncWorkLimits, cores: int | None = None) -> None:
        self.limits = limits
        self.cores = cores or os.cpu_count() or 1
        self.in_flight = WorkEstimate(0.0, 0)
        self._changed: asyncio.Condition | None = None  # made in the event loop on first use

    def check(self, estimate: WorkEstimate, what: str, instead: str) -> None:
        """413 when ``estimate`` is over one request's limits. ``what`` names the work ("wmf on a 7000x7000
        output"), ``instead`` says where such work goes (a route, a smaller request)."""
        over = []
        if estimate.cpu_seconds > self.limits.max_cpu_seconds:
            over.append(f"about {estimate.cpu_seconds:,.1f} CPU-seconds (the limit is "
                        f"{self.limits.max_cpu_seconds:,.1f}, SWEEPCAST_SYNC_MAX_CPU_SECONDS)")
        if estimate.peak_bytes > self.limits.max_memory_bytes:
            over.append(f"about {_mb(estimate.peak_bytes)} of memory (the limit is "
                        f"{_mb(self.limits.max_memory_bytes)}, SWEEPCAST_SYNC_MAX_MEMORY_MB)")
        if over:
            raise ApiError(413, f"{what} would take {' and '.join(over)}: too much for a synchronous request; "
                                f"{instead}", "too_much_work")

    @asynccontextmanager
    async def admit(self, estimate: WorkEstimate) -> AsyncIterator[None]:
        """Hold ``estimate``'s memory in the budget while the block runs; 503 with Retry-After when no room comes
        within ``wait_seconds``. A request over the whole budget (only with a per-request limit above it) waits
        for an empty budget."""
        need = min(estimate.peak_bytes, self.limits.budget_bytes)
        changed = self._condition()
        async with changed:
            try:
                await asyncio.wait_for(changed.wait_for(lambda: self.in_flight.peak_bytes + need
                                                        <= self.limits.budget_bytes), self.limits.wait_seconds)
            except TimeoutError:
                retry = max(1, math.ceil(self.in_flight.cpu_seconds / self.cores))
                raise ApiError(503, f"the service is busy with other large requests ({_mb(self.in_flight.peak_bytes)}"
                                    f" of the {_mb(self.limits.budget_bytes)} it gives synchronous work, "
                                    f"SWEEPCAST_SYNC_MEMORY_BUDGET_MB); retry after {retry} s", "busy",
                               headers={"Retry-After": str(retry)}) from None
            held = WorkEstimate(estimate.cpu_seconds, need)
            self.in_flight += held
        try:
            yield
        finally:
            async with changed:
                self.in_flight = WorkEstimate(self.in_flight.cpu_seconds - held.cpu_seconds,
                                              self.in_flight.peak_bytes - held.peak_bytes)
                changed.notify_all()

    async def run(self, estimate: WorkEstimate, work: Callable[[], Awaitable[R]]) -> R:
        """``await work()`` (the request's compute, on the compute threads) within :meth:`admit`. A request cancelled
        meanwhile (its client gone) keeps its share of the budget until its thread has finished: the work goes on
        in the thread and its memory with it."""
        async with self.admit(estimate):
            running = asyncio.ensure_future(work())
            try:
                return await asyncio.shield(running)
            except asyncio.CancelledError:
                await asyncio.wait({running})
                raise

    def _condition(self) -> asyncio.Condition:
        if self._changed is None:
            self._changed = asyncio.Condition()
        return self._changed
