"""The demo rig's viewer session, started ahead of its first viewer and kept warm.

A new user's first look at the renderer is the demo in the browser. Without this, their first frame
waits for a session actor to start (a Ray worker process), for it to read the recording and build the
renderer, and for the first render to set up its buffers: over a second on two cores, after the
service was already ready. Here the service does that once the demo recording is ready, renders one
view the way the browser viewer will, and touches the session while it runs so that it never idles
out; the first viewer then finds it warm (``session/<rig>/<recording>`` is the actor every viewer of
the demo's newest recording shares).
"""
from __future__ import annotations

import asyncio
import logging

from app.stored_rigs import recording_views, session_config
from app.services import Services
from workers.streaming import store as rigstore
from workers.streaming.actor import SessionClient
from workers.streaming.session import SessionError
from workers.streaming.params import Viewpoint

log = logging.getLogger("sweepcast.demo")

POLL_SECONDS = 0.25  # while the demo recording is made: a few seconds after a first start
PRESTART_VIEWER = "prestart"


async def demo_recording(svc: Services) -> tuple[str, str] | None:
    """(rig id, id of its newest ready recording) of the demo rig, or None while there is none."""
    metas = [m for m in await asyncio.to_thread(rigstore.list_rig_metas, svc.store) if m.get("demo")]
    if not metas:
        return None
    ready = [r for r in await recording_views(svc, metas[0]["id"]) if r["state"] == "ready"]
    return (metas[0]["id"], ready[-1]["id"]) if ready else None


def first_view(svc: Services) -> Viewpoint:
    """The view the browser viewer asks for first: its default pose at the configured starting size."""
    width, height = svc.settings.viewer_size_px
    return Viewpoint(id=0, width=width, height=height)


async def keep_demo_session_warm(svc: Services) -> None:
    """Once Ray is up and the demo recording ready, start its session and render one view; then touch it
    every third of the idle timeout while the service runs. Never raises (the viewer works without it)."""
    if not svc.settings.demo_rig:
        return
    try:
        await svc.dispatcher.ray_ready.wait()
        while (found := await demo_recording(svc)) is None:
            await asyncio.sleep(POLL_SECONDS)
        client = SessionClient(session_config(svc, *found), svc.settings.session_resources)
        await client.info()
        try:
            header, _ = await client.view(PRESTART_VIEWER, first_view(svc))
            first = f"{header['render_ms']:.0f} ms"
        except SessionError as exc:
            first = exc.code
        await client.leave(PRESTART_VIEWER)
        log.info("demo session %s/%s warm (first render %s)", *found, first)
        while True:
            await asyncio.sleep(max(svc.settings.session_idle_seconds / 3, 0.2))
            await client.touch()
    except asyncio.CancelledError:
        raise
    except Exception:  # noqa: BLE001 - the first viewer starts the session instead
        log.exception("could not keep the demo session warm")
