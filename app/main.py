"""The FastAPI application: ``create_app(settings)``."""
from __future__ import annotations

import asyncio
import json
import logging
import time
from contextlib import asynccontextmanager
from pathlib import Path
from typing import AsyncIterator

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles

from app import raycluster
from app.auth import ApiKeyMiddleware
from app.errors import install_error_handlers
from app.kernelcache import KernelWarmup
from app.limits import BodyLimitMiddleware, BodyPace, RouteBodyLimits
from app.socket_transport import TransportApp
from app.logredact import install_log_redaction
from app.openapi_doc import install_contract
from app.ray_watch import watch_ray
from app.services import Services, build_services
from app.settings import Settings
from workers.common.models import MODELS, ModelError, install, installed
from workers.common.packages import package_version

log = logging.getLogger("sweepcast")

API_DESCRIPTION = """
sweepcast takes synchronised camera streams or uploaded media, queues jobs to worker processes
and streams results back.

Every `/v1` route and socket needs `Authorization: Bearer <key>` when the service has API keys. A user key sees
and changes only what it created (jobs, rigs, recordings, face models, sessions): another key's resource answers
404, as one that does not exist. The demo rig is readable by every key. Admin keys (`SWEEPCAST_API_KEYS`, or
made with role admin) see everything and manage keys at `/v1/keys`. Each user key has quotas (bytes stored, jobs
queued or running, viewer sessions, uploads per minute): past one, 429 with `Retry-After` or 507;
`GET /v1/keys/me` shows the limits and the usage.
Errors are JSON: `{"error": "<code>", "detail": "<what was wrong>"}`.

Virtual views stream over two WebSockets (not listed below; see docs/viewer.md): `/v1/rigs/{rig_id}/view` for
viewers and `/v1/rigs/{rig_id}/live` for live camera frame sets. A viewer either sends viewpoints and gets JPEG
frames rendered by the server, or, opened with `?render=browser`, renders every view itself (WebGL2, as the viewer
page at `/viewer/` does where it can): it sends no viewpoints; the socket's hello carries the rig's geometry, and
frame sets come from `GET /v1/rigs/{rig_id}/recordings/{recording_id}/frames/{frame}` (immutable, cacheable) or,
for the live stream, over the socket as they arrive (the background model from `GET /v1/rigs/{rig_id}/live/background`).
"""


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        svc = await asyncio.to_thread(build_services, settings)
        app.state.services = svc
        if settings.warm_kernels:
            svc.warmup = KernelWarmup.start(settings.resolved_numba_cache_dir)
        starter = asyncio.create_task(_start_ray(svc))
        demo = asyncio.create_task(ensure_demo_rig(svc))
        demo_session = asyncio.create_task(keep_demo_session_warm(svc))
        fetcher = asyncio.create_task(fetch_missing_models(settings))
        try:
            yield
        finally:
            starter.cancel()
            demo.cancel()
            demo_session.cancel()
            fetcher.cancel()
            svc.warmup.stop()
            await svc.dispatcher.shutdown()
            if svc.ray_owned:
                import ray

                await asyncio.to_thread(ray.shutdown)
            svc.jobs.close()
            svc.compute.shutdown(wait=False, cancel_futures=True)

    app = TransportApp(
        title="sweepcast",
        version=package_version("sweepcast") or "0.0.0",
        description=API_DESCRIPTION,
        lifespan=lifespan,
    )
    app.state.settings = settings
    install_error_handlers(app)
    install_contract(app)  # /openapi.json says what the service really answers

    install_log_redaction()  # ?access_token= stays out of uvicorn's request lines

    limits = {"json": settings.max_json_bytes, "upload": settings.max_upload_bytes, "batch": settings.max_batch_bytes}
    pace = BodyPace(settings.upload_idle_seconds, 60.0, settings.min_upload_bytes_per_second)
    app.add_middleware(BodyLimitMiddleware, limit_for=RouteBodyLimits(limits), pace=pace)
    app.add_middleware(ApiKeyMiddleware)  # added last: runs first, before any body is read

    from app.routers import (depth, faces, jobs, keys, photos, reconstructions, recordings, review, rig_sockets,
                             rigs, sessions, system)
    from app.demo_session import keep_demo_session_warm
    from app.demo_rig import ensure_demo_rig

    app.include_router(system.router)
    app.include_router(jobs.router)
    app.include_router(jobs.ws_router)
    app.include_router(photos.router)
    app.include_router(review.router)
    app.include_router(review.page_router)
    app.include_router(depth.router)
    app.include_router(faces.router)
    app.include_router(reconstructions.router)
    app.include_router(rigs.router)
    app.include_router(recordings.router)
    app.include_router(sessions.router)
    app.include_router(keys.router)
    app.include_router(rig_sockets.ws_router)
    app.mount("/viewer", StaticFiles(directory=Path(__file__).parent / "static", html=True), name="viewer")
    app.mount("/review/assets", StaticFiles(directory=review.PAGE), name="review-assets")
    return app


RAY_RETRY_S = 5.0


async def _start_ray(svc: Services) -> None:
    """Connect Ray off the event loop (it takes seconds), then recover and start dispatching. A cluster that
    cannot be reached yet (its head is down or still starting) is tried again every few seconds: meanwhile the
    API answers, ``/readyz`` says why it is not ready, and accepted jobs wait for it."""
    failures = 0
    while True:
        try:
            svc.ray_owned = await asyncio.to_thread(raycluster.connect_for, svc.settings)
            break
        except Exception as exc:  # noqa: BLE001 - reported by /readyz and the log; the API still answers
            svc.ray_error = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
            if not svc.settings.ray_address:  # the embedded cluster failed to start: trying again will not help
                log.exception("could not start Ray")
                return
            if failures % 12 == 0:  # once a minute
                log.warning("the Ray cluster at %s cannot be reached (%s); trying again every %g s",
                            svc.settings.ray_address, svc.ray_error, RAY_RETRY_S)
            failures += 1
            raycluster.forget_connect_attempt()
            await asyncio.sleep(RAY_RETRY_S)
    if failures:
        log.info("connected to the Ray cluster at %s", svc.settings.ray_address)
    svc.ray_error = None
    svc.dispatcher.ray_ready.set()
    await svc.dispatcher.start()
    if svc.settings.ray_address:  # a cluster of its own: its head can be lost and come back
        await watch_ray(svc)
    elif svc.ray_owned and svc.settings.warm_workers:
        await _prepare_workers(svc)


async def _prepare_workers(svc: Services) -> None:
    """The embedded cluster's idle workers made ready for batch jobs (:mod:`workers.prewarm`), in the background."""
    count = raycluster.idle_worker_limit(svc.settings.ray_num_cpus, svc.settings.ray_idle_workers)
    started = time.monotonic()
    try:
        ready = await raycluster.prepare_workers(count)
    except Exception as exc:  # noqa: BLE001 - the first tasks then do it themselves, as without the warm-up
        log.warning("the Ray workers could not be made ready ahead: %s: %s", type(exc).__name__, exc)
        return
    engines = sorted({str(r["engine"]) for r in ready})
    log.info("%d Ray worker processes ready for batch jobs in %.1f s (orientation engine: %s)",
             len({r["pid"] for r in ready}), time.monotonic() - started, ", ".join(engines))


async def fetch_missing_models(settings: Settings) -> None:
    """Download the optional models not yet in ``<data_dir>/models`` (when ``fetch_models`` is on and no
    setting names another file). Never raises: offline, the engines work without them."""
    if not settings.fetch_models:
        return
    for model in MODELS.values():
        if installed(model, settings.data_dir) or (model.name == "yunet" and settings.orientation_yunet_model):
            continue
        try:
            path = await asyncio.to_thread(install, model, settings.data_dir)
            log.info("installed the %s model at %s (%s)", model.name, path, model.used_for)
        except ModelError as exc:
            log.warning("optional model %s not installed: %s; 'sweepcast models fetch %s --from FILE' installs "
                        "a copy you have", model.name, exc, model.name)


def render_openapi() -> str:
    """The app's OpenAPI document (:func:`app.openapi_doc.document_contract`), serialised stably (sorted keys,
    2-space indent, trailing newline): what ``sweepcast openapi`` commits."""
    app = create_app(Settings(api_keys=[]))
    return json.dumps(app.openapi(), indent=2, sort_keys=True) + "\n"
