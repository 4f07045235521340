"""Following a Ray cluster the service does not own (``SWEEPCAST_RAY_ADDRESS``) through the loss of its head.

When the head stops answering, running tasks go on (their workers and the API talk directly) but nothing new is
scheduled, and ``/readyz`` says so. When a head answers again, even one that came back with its state from Redis
(Ray's GCS fault tolerance), this process's Ray client schedules nothing more (measured: a task submitted after the
restart waited forever; after ``ray.shutdown()`` and ``ray.init()`` it ran at once). So the service connects again
and resumes the jobs it was following: each open attempt counts as interrupted by a restart (never against the
job's retry budget) and is submitted again.
"""
from __future__ import annotations

import asyncio
import logging

from app import raycluster
from app.services import Services

log = logging.getLogger("sweepcast.ray")

CHECK_EVERY_S = 5.0
ANSWER_WITHIN_S = 3.0


async def watch_ray(svc: Services) -> None:
    """Run for as long as the service: notice the head's loss and return (see the module docstring)."""
    lost = False
    pending: asyncio.Future | None = None
    while True:
        await asyncio.sleep(CHECK_EVERY_S)
        if pending is None or pending.done():  # one check at a time: a lost head holds a thread per call
            pending = asyncio.ensure_future(asyncio.to_thread(raycluster.ready))
        try:
            ok, detail = await asyncio.wait_for(asyncio.shield(pending), ANSWER_WITHIN_S)
        except asyncio.TimeoutError:
            ok, detail = False, f"no answer within {ANSWER_WITHIN_S:g} s"
        except Exception as exc:  # noqa: BLE001 - a failed check is a lost cluster
            ok, detail = False, f"{type(exc).__name__}: {exc}"
        if not ok and not lost:
            lost = True
            svc.ray_error = (f"the Ray cluster at {svc.settings.ray_address} does not answer ({detail}): its head may "
                             "be down; running jobs go on, new ones wait for it")
            log.warning("%s", svc.ray_error)
        elif ok and lost:
            await _reconnect(svc)
            lost = False


async def _reconnect(svc: Services) -> None:
    log.warning("the Ray cluster at %s answers again: connecting anew and resuming the jobs this replica follows",
                svc.settings.ray_address)
    svc.dispatcher.ray_ready.clear()
    await asyncio.to_thread(raycluster.reconnect, svc.settings)
    svc.dispatcher.ray_ready.set()
    resumed = await svc.dispatcher.restart_attempts()
    svc.ray_error = None
    log.info("reconnected to the Ray cluster; %d job(s) resumed", resumed)
