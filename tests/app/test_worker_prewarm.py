"""The embedded cluster's workers made ready at start-up (workers/prewarm.py): each in a process of its own, with the
orientation engine a batch job would build."""
from __future__ import annotations

import asyncio
import os
import time

from workers.orientation.detect import detector_config, get_detector
from workers.prewarm import prepare_worker
from workers.settings import worker_settings


def test_a_prepared_worker_holds_the_engine_a_batch_job_builds_and_waits_for_the_others(tmp_path):
    settings = worker_settings()
    engine = get_detector(detector_config(settings, settings.models_dir))
    barrier = tmp_path / "barrier"
    barrier.mkdir()
    started = time.monotonic()
    ready = prepare_worker(barrier, count=2, timeout_s=0.5)  # the other never comes: it stops waiting
    assert time.monotonic() - started >= 0.5
    assert ready["pid"] == os.getpid() and ready["engine"] == engine.name
    assert [p.name for p in barrier.iterdir()] == [str(os.getpid())]


def test_the_service_prepares_each_idle_worker_in_a_process_of_its_own(ray_local):
    from app import raycluster

    ready = asyncio.run(raycluster.prepare_workers(2, timeout_s=120))
    assert len({r["pid"] for r in ready}) == 2 and os.getpid() not in {r["pid"] for r in ready}
    assert all(r["engine"] for r in ready)
