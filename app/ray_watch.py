"""Following a Ray cluster the service does not own (``SWEEPCAST_RAY_ADDRESS``) through the loss of its head.

When the head stops answering, running tasks go on (their workers and the API talk directly) but nothing new is
scheduled, and ``/readyz`` says so. When a head answers again, even one that came back with its state from Redis
(Ray's GCS fault tolerance), this process's Ray client schedules nothing more (measured: a task submitted after the
restart waited forever). Connecting anew in the process (``ray.shutdown()``, ``ray.init()``) made the task run, but
a thread still holding a Ray handle at that moment (a viewer's session actor, a readiness check) ended the whole
process ("the core worker has already been shutdown"). So the service stops instead: it gives back the jobs it was
following (their open attempts count as interrupted by a restart, never against their retry budget) and exits with
:data:`RESTART_EXIT_CODE` at once (a graceful server shutdown hung on requests the stale client held), for its
service manager to start it again (the compose file's restart policy); the new process connects to the head that is
back and resumes those jobs.
"""
from __future__ import annotations

import asyncio
import logging
import os

from app import raycluster
from app.services import Services, answer_within

log = logging.getLogger("sweepcast.ray")

CHECK_EVERY_S = 5.0
ANSWER_WITHIN_S = 3.0
RESTART_EXIT_CODE = 75  # EX_TEMPFAIL: start me again
GIVE_BACK_WITHIN_S = 30.0


async def watch_ray(svc: Services) -> None:
    """Run for as long as the service: note the head's loss (``/readyz`` says it), and stop the process once a head
    answers again (see the module docstring)."""
    lost = False
    while True:
        await asyncio.sleep(CHECK_EVERY_S)
        found = await answer_within(raycluster.ready, "the Ray cluster", ANSWER_WITHIN_S)
        ok, detail = found if isinstance(found, tuple) else (False, found)
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
