"""The gate of synchronous work: one request's limits, and the shared memory budget with a bounded wait."""
from __future__ import annotations

import asyncio

import pytest

from app.errors import ApiError
from app.sync_work import SyncWorkGate, SyncWorkLimits
from workers.common.work import WorkEstimate

MB = 2**20


def gate(budget_mb: float = 10, wait: float = 0.2) -> SyncWorkGate:
    limits = SyncWorkLimits(max_cpu_seconds=5, max_memory_bytes=int(8 * MB), budget_bytes=int(budget_mb * MB),
                            wait_seconds=wait)
    return SyncWorkGate(limits, cores=2)


def test_one_request_over_either_limit_is_413_saying_what_and_instead():
    g = gate()
    g.check(WorkEstimate(5.0, 8 * MB), "wmf on a 10x10 output", "use the job")  # at the limits: admitted
    with pytest.raises(ApiError) as exc:
        g.check(WorkEstimate(5.5, 1), "wmf on a 10x10 output", "use the job")
    assert exc.value.status_code == 413 and exc.value.code == "too_much_work"
    assert "about 5.5 CPU-seconds" in exc.value.detail and exc.value.detail.endswith("use the job")
    with pytest.raises(ApiError) as exc:
        g.check(WorkEstimate(0.1, 9 * MB), "x", "y")
    assert "9 MB of memory" in exc.value.detail and "SWEEPCAST_SYNC_MAX_MEMORY_MB" in exc.value.detail


def test_requests_wait_for_room_in_the_budget_and_run_when_it_frees():
    async def scenario() -> list[str]:
        g, order = gate(budget_mb=10, wait=5), []

        async def request(name: str, mb: float, seconds: float) -> None:
            async with g.admit(WorkEstimate(1.0, int(mb * MB))):
                order.append(f"{name} in")
                await asyncio.sleep(seconds)
                order.append(f"{name} out")

        first = asyncio.create_task(request("a", 6, 0.1))
        await asyncio.sleep(0.01)
        await asyncio.gather(first, request("b", 6, 0), request("c", 3, 0))
        assert g.in_flight == WorkEstimate(0.0, 0)
        return order

    order = asyncio.run(scenario())
    assert order.index("b in") > order.index("a out")  # 6 + 6 MB is over the 10 MB budget: b waited for a
    assert order.index("c in") < order.index("a out")  # 6 + 3 MB fits: c ran beside a


def test_no_room_within_the_wait_is_503_with_retry_after():
    async def scenario() -> ApiError:
        g = gate(budget_mb=10, wait=0.05)
        async with g.admit(WorkEstimate(7.0, 10 * MB)):
            with pytest.raises(ApiError) as exc:
                async with g.admit(WorkEstimate(1.0, 1 * MB)):
                    pass
        async with g.admit(WorkEstimate(1.0, 10 * MB)):  # the budget came back whole
            pass
        return exc.value

    err = asyncio.run(scenario())
    assert err.status_code == 503 and err.code == "busy"
    assert err.headers == {"Retry-After": "4"}  # 7 CPU-seconds in flight on 2 cores


def test_a_cancelled_request_keeps_its_budget_until_its_thread_ends():
    import threading
    from concurrent.futures import ThreadPoolExecutor

    async def scenario() -> None:
        g, release, pool = gate(budget_mb=10), threading.Event(), ThreadPoolExecutor(1)
        loop = asyncio.get_running_loop()
        work = lambda: loop.run_in_executor(pool, release.wait)  # noqa: E731
        request = asyncio.create_task(g.run(WorkEstimate(1.0, 6 * MB), work))
        await asyncio.sleep(0.05)
        request.cancel()  # the client went away; the thread computes on
        await asyncio.sleep(0.05)
        assert not request.done() and g.in_flight.peak_bytes == 6 * MB
        release.set()
        with pytest.raises(asyncio.CancelledError):
            await request
        assert g.in_flight == WorkEstimate(0.0, 0)
        pool.shutdown()

    asyncio.run(scenario())
