"""Liveness, readiness and the front page."""
from __future__ import annotations

import asyncio

from fastapi import APIRouter, Depends
from fastapi.responses import HTMLResponse, JSONResponse

from app import raycluster
from app.routers.photos import orientation_config
from app.services import Services, answer_within, services, storage_check
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


@router.get("/readyz", summary="Readiness: the database and Ray are reachable (also reports what the orientation "
                                "engine uses: face detector, YuNet model, tesseract for the text cue)",
            responses={503: {"description": "not ready; the body says which part is missing"}})
async def readyz(svc: Services = Depends(services)) -> JSONResponse:
    checks: dict[str, dict[str, object]] = {}
    database = await answer_within(svc.jobs.ping, "the job database")
    checks["database"] = {"ok": True} if database is None else {"ok": False, "detail": database}
    if svc.ray_error:
        checks["ray"] = {"ok": False, "detail": svc.ray_error}
    else:
        found = await answer_within(raycluster.ready, "the Ray cluster")
        ok, detail = found if isinstance(found, tuple) else (False, found)
        checks["ray"] = {"ok": ok and svc.dispatcher.ray_ready.is_set(), "detail": detail}
    # The orientation engine's optional parts (YuNet; the text cue and where its data came from): reported, never a
    # reason to be unready.
    checks["orientation"] = await asyncio.to_thread(engine_status, orientation_config(svc.settings))
    checks["storage"] = await asyncio.to_thread(storage_check, svc)
    checks["kernels"] = svc.warmup.status()  # compiled ahead of the first request: reported, never unready
    ready = all(c["ok"] for c in checks.values())
    return JSONResponse({"status": "ready" if ready else "not ready", "checks": checks}, 200 if ready else 503)
