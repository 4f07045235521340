"""The demo rig at start-up: its recording, when `sweepcast warmup` (or an earlier data folder) kept one, is
published by the service itself before Ray is up; without one, its job goes to Ray and renders it."""
from __future__ import annotations

import asyncio

import app.demo_rig as demo_module
from app.demo_rig import ensure_demo_rig
from app.stored_rigs import recording_views
from app.services import build_services
from app.settings import Settings
from workers.runtime import results_prefix
from workers.streaming import store as rigstore
from workers.streaming.demo import demo_recording, demo_rig

SMALL = demo_rig(2, (32, 24))


def _services(tmp_path, monkeypatch):
    monkeypatch.setattr(demo_module, "demo_rig", lambda: SMALL)
    svc = build_services(Settings(data_dir=tmp_path / "data"))
    submitted: list[str] = []
    monkeypatch.setattr(svc.dispatcher, "submit", submitted.append)
    return svc, submitted


def _demo_recordings(svc) -> list[dict]:
    (meta,) = [m for m in rigstore.list_rig_metas(svc.store) if m.get("demo")]
    return asyncio.run(recording_views(svc, meta["id"]))


def test_a_kept_recording_is_published_without_ray(tmp_path, monkeypatch):
    svc, submitted = _services(tmp_path, monkeypatch)
    kept = tmp_path / "rendered.zip"
    demo_recording(SMALL, kept, 12, 6.0, svc.settings.resolved_demo_cache_dir)  # what `sweepcast warmup` does
    asyncio.run(ensure_demo_rig(svc))
    assert submitted == [] and not svc.dispatcher.ray_ready.is_set()
    (recording,) = _demo_recordings(svc)
    assert recording["state"] == "ready"
    job = svc.jobs.get(recording["id"])
    assert (job.state, job.attempts, job.error) == ("succeeded", 1, None)
    assert job.result["summary"] == {"frames": 12, "fps": 6.0, "cameras": 2, "background": "given"}
    assert [f["name"] for f in job.result["files"]] == ["frames.zip"]
    assert svc.store.read(f"{results_prefix(job.id)}/frames.zip") == kept.read_bytes()


def test_without_a_kept_recording_its_job_goes_to_ray(tmp_path, monkeypatch):
    svc, submitted = _services(tmp_path, monkeypatch)
    asyncio.run(ensure_demo_rig(svc))
    (recording,) = _demo_recordings(svc)
    assert submitted == [recording["id"]] and recording["state"] == "processing"


def test_a_kept_recording_that_cannot_be_published_goes_to_ray(tmp_path, monkeypatch):
    svc, submitted = _services(tmp_path, monkeypatch)
    demo_recording(SMALL, tmp_path / "rendered.zip", 12, 6.0, svc.settings.resolved_demo_cache_dir)

    def broken(*args):
        raise OSError("disk full")

    monkeypatch.setattr("app.dispatcher.publish_results", broken)
    asyncio.run(ensure_demo_rig(svc))
    (recording,) = _demo_recordings(svc)
    assert submitted == [recording["id"]] and recording["state"] in ("processing", "queued")
    assert svc.jobs.get(recording["id"]).state in ("queued", "running")
