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
import os

from app import raycluster
from app.services import Services

log = logging.getLogger("sweepcast.ray")

CHECK_EVERY_S = 5.0
ANSWER_WITHIN_S = 3.0
RESTART_EXIT_CODE = 75  # EX_TEMPFAIL: start me again
GIVE_BACK_WITHIN_S = 30.0


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
            await _stop_to_restart(svc)


async def _stop_to_restart(svc: Services) -> None:
    log.warning("the Ray cluster at %s answers again after its head was lost; this process's Ray client cannot "
                "schedule on it any more: giving its jobs back and exiting (code %d) to be started again",
                svc.settings.ray_address, RESTART_EXIT_CODE)
    try:
        await asyncio.wait_for(svc.dispatcher.shutdown(cancel_tasks=False), GIVE_BACK_WITHIN_S)
    except Exception:  # noqa: BLE001 - what was not given back is resumed when its lease runs out
        log.exception("could not give every job back")
    logging.shutdown()
    os._exit(RESTART_EXIT_CODE)
