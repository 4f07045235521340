"""Liveness, readiness and the front page."""
from __future__ import annotations

import asyncio
from typing import Callable, TypeVar

from fastapi import APIRouter, Depends
from fastapi.responses import HTMLResponse, JSONResponse

from app import raycluster
from app.routers.photos import orientation_config
from app.services import Services, services, storage_check
from workers.orientation.orient import engine_status

router = APIRouter(tags=["system"])


@router.get("/", response_class=HTMLResponse, include_in_schema=False)
def index() -> str:
    return (
        "<!doctype html><title>sweepcast</title><h1>sweepcast</h1>"
        "<p>Streaming video-processing service. <a href='/docs'>API documentation</a> · "
        "<a href='/openapi.json'>OpenAPI</a></p>"
    )


@router.get("/healthz", summary="Liveness: the process answers")
async def healthz() -> dict[str, str]:
    # answered on the event loop itself: a sync route hops through Starlette's thread pool and back, which
    # under 50 photo uploads on 2 busy cores added tens of ms to the probe's p99
    return {"status": "ok"}


T = TypeVar("T")
READY_CHECK_TIMEOUT_S = 3.0
_pending: dict[tuple[str, int], asyncio.Future] = {}
"""Checks that outlived their probe, by what they check: a probe does not start another while one hangs (each
would hold a thread for as long as the backend does)."""


async def _within(check: Callable[[], T], what: str) -> T | str | None:
    """``check()`` off the event loop, given :data:`READY_CHECK_TIMEOUT_S`: its result (None for none), or why it
    failed. A backend that hangs (a frozen database, a Ray head that is gone) makes readiness say so instead of
    holding the probe."""
    key = (what, id(getattr(check, "__self__", check)))  # one app's database is not another's (tests)
    running = _pending.get(key)
    if running is not None and not running.done():
        return f"{what} has not answered an earlier check yet"
    future = _pending[key] = asyncio.ensure_future(asyncio.to_thread(check))
    try:
        return await asyncio.wait_for(asyncio.shield(future), READY_CHECK_TIMEOUT_S)
    except asyncio.TimeoutError:
        return f"{what} did not answer within {READY_CHECK_TIMEOUT_S:g} s"
    except Exception as exc:  # noqa: BLE001 - reported, not raised
        return f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"


@router.get("/readyz", summary="Readiness: the database and Ray are reachable (also reports what the orientation "
                                "engine uses: face detector, YuNet model, tesseract for the text cue)",
            responses={503: {"description": "not ready; the body says which part is missing"}})
async def readyz(svc: Services = Depends(services)) -> JSONResponse:
    checks: dict[str, dict[str, object]] = {}
    database = await _within(svc.jobs.ping, "the job database")
    checks["database"] = {"ok": True} if database is None else {"ok": False, "detail": database}
    if svc.ray_error:
        checks["ray"] = {"ok": False, "detail": svc.ray_error}
    else:
        found = await _within(raycluster.ready, "the Ray cluster")
        ok, detail = found if isinstance(found, tuple) else (False, found)
        checks["ray"] = {"ok": ok and svc.dispatcher.ray_ready.is_set(), "detail": detail}
    # The orientation engine's optional parts (YuNet, tesseract): reported, never a reason to be unready.
    checks["orientation"] = await asyncio.to_thread(engine_status, orientation_config(svc.settings))
    checks["storage"] = await asyncio.to_thread(storage_check, svc)
    checks["kernels"] = svc.warmup.status()  # compiled ahead of the first request: reported, never unready
    ready = all(c["ok"] for c in checks.values())
    return JSONResponse({"status": "ready" if ready else "not ready", "checks": checks}, 200 if ready else 503)
