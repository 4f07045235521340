"""The first-run demo rig: the procedural arc rig and its recording, made at start-up when there is none."""
from __future__ import annotations

import asyncio
import logging

from app.keys import SERVICE_ADMIN
from app.services import Services, Upload, create_job
from app.stored_rigs import load_rig, recording_views, rig_json_bytes
from workers.streaming import store as rigstore
from workers.streaming.demo import DEMO_NAME, cached_demo_recording, demo_rig
from workers.streaming.job import DEMO_JOB
from workers.streaming.params import DemoParams
from workers.streaming.store import ARCHIVE_NAME

log = logging.getLogger("sweepcast.rigs")


async def ensure_demo_rig(svc: Services) -> None:
    """At start-up (when ``demo_rig`` is on): store the procedural arc rig when there is no demo rig,
    and start the job that renders its recording when it has none ready or under way (a first
    attempt may have failed). Never raises: the service is useful without the demo."""
    if not svc.settings.demo_rig:
        return
    try:
        metas = [m for m in await asyncio.to_thread(rigstore.list_rig_metas, svc.store) if m.get("demo")]
        if metas:
            rig_id = metas[0]["id"]
            if any(r["state"] in ("ready", "processing") for r in await recording_views(svc, rig_id)):
                return
            rig = await load_rig(svc, rig_id)
        else:
            rig = demo_rig()
            rig_id = rigstore.new_rig_id()
            await asyncio.to_thread(rigstore.save_rig, svc.store, rig_id, rig,
                                    {"name": DEMO_NAME, "format": "json", "demo": True})
        params = DemoParams()
        kept = await asyncio.to_thread(cached_demo_recording, svc.settings.resolved_demo_cache_dir, rig,
                                       params.frames, params.fps)
        job = await create_job(svc, SERVICE_ADMIN, DEMO_JOB, params, [Upload("rig", rig_json_bytes(rig), {"filename": "rig.json"})],
                               submit=False)
        await asyncio.to_thread(rigstore.save_recording_meta, svc.store, rig_id, job.id,
                                {"name": "demo recording", "kind": "demo"})
        # The recording kept by `sweepcast warmup` (or an earlier data folder's demo job) is the job's result as
        # it is: published here, before Ray is even up, so that the demo's viewer session can start with Ray.
        if kept is not None and await svc.dispatcher.finish_here(job.id, {ARCHIVE_NAME: kept[0]}, kept[1].summary()):
            log.info("demo rig %s: its recording %s is the one kept in %s", rig_id, job.id, kept[0].parent)
            return
        svc.dispatcher.submit(job.id)
        log.info("demo rig %s: its recording is being rendered by job %s", rig_id, job.id)
    except Exception:  # noqa: BLE001 - the service is useful without the demo
        log.exception("could not create the demo rig")
