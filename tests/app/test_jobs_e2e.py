"""The job system end to end on the real orientation batch job: events, results, cancel, durability."""
from __future__ import annotations

import os
import signal
import time

import pytest

from harness.photos import FACES_ONLY, batch_files
from harness.scenarios import run_scenario


def wait_final(client, job_id: str, timeout: float = 120.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if job["state"] in ("succeeded", "failed", "cancelled"):
            return job
        time.sleep(0.05)
    raise AssertionError(f"job {job_id} did not finish: {client.get(f'/v1/jobs/{job_id}').json()}")


def test_batch_with_one_corrupt_photo_streams_events_and_results(client_factory):
    client = client_factory()
    r = client.post("/v1/photos/batches", files=batch_files(4, corrupt_at=2))
    assert r.status_code == 202, r.text
    job = r.json()
    assert r.headers["location"] == f"/v1/jobs/{job['id']}"
    assert job["state"] == "queued" and len(job["inputs"]) == 4

    with client.websocket_connect(f"/v1/jobs/{job['id']}/events") as ws:
        events = []
        while True:
            event = ws.receive_json()
            events.append(event)
            if event["type"] == "final":
                break
    types = [e["type"] for e in events]
    assert types[0] in ("snapshot", "final")
    final = events[-1]["job"]
    assert final["state"] == "succeeded", final
    if types[0] == "snapshot":  # followed live: one progress event per photo
        assert sum(1 for e in events if e["type"] == "progress") >= 4

    names = {f["name"] for f in final["result"]["files"]}
    assert "report.json" in names
    report = client.get(f"/v1/jobs/{job['id']}/results/report.json")
    assert report.status_code == 200
    entries = report.json()
    assert [e["filename"] for e in entries] == [f"photo {i}.jpg" for i in range(4)]
    assert [bool(e.get("error")) for e in entries] == [False, False, True, False]
    assert client.get(f"/v1/jobs/{job['id']}/results/../../etc/passwd").status_code == 404
    assert client.get(f"/v1/jobs/{job['id']}/results/nope.txt").status_code == 404


def test_cancel_then_delete(client_factory):
    client = client_factory()
    job = client.post("/v1/photos/batches", files=batch_files(60, width=1600, height=1200), data=FACES_ONLY).json()
    deadline = time.monotonic() + 60
    while client.get(f"/v1/jobs/{job['id']}").json()["state"] == "queued" and time.monotonic() < deadline:
        time.sleep(0.02)
    r = client.delete(f"/v1/jobs/{job['id']}")
    assert r.status_code == 200 and r.json()["state"] == "cancelled"
    assert client.get(f"/v1/jobs/{job['id']}/results/report.json").status_code == 409
    assert client.delete(f"/v1/jobs/{job['id']}").status_code == 204
    assert client.get(f"/v1/jobs/{job['id']}").status_code == 404


def test_worker_killed_mid_batch_is_retried_and_nothing_is_lost(client_factory):
    client = client_factory()
    # enough photos that the job is still running when its worker is killed after the first one, small ones so
    # that both attempts take seconds
    job = client.post("/v1/photos/batches", files=batch_files(16, width=800, height=600), data=FACES_ONLY).json()
    with client.websocket_connect(f"/v1/jobs/{job['id']}/events") as ws:
        while True:
            event = ws.receive_json()
            if event["type"] == "progress" and "done" in event:  # a photo done (not the row's "running")
                break
            assert event["type"] in ("snapshot", "started", "progress"), event
            if event["type"] == "started":
                pid = event["pid"]
        os.kill(pid, signal.SIGKILL)  # the job's own worker, once a block of photos is done
        later = []
        while later[-1:] == [] or later[-1]["type"] != "final":
            later.append(ws.receive_json())
    final = wait_final(client, job["id"])
    assert final["state"] == "succeeded", final
    assert final["attempts"] >= 2
    assert final["worker_losses"] >= 1 and final["service_restarts"] == 0
    entries = client.get(f"/v1/jobs/{job['id']}/results/report.json").json()
    assert len(entries) == 16 and not any(e.get("error") for e in entries)
    resumed = [e for e in later if e["type"] == "progress" and "done by an earlier attempt" in e["stage"]]
    assert resumed and resumed[0]["done"] >= 1  # the next attempt took up what the lost one finished


def test_jobs_queued_when_the_service_stops_complete_after_restart(ray_local, settings_factory):
    from fastapi.testclient import TestClient

    from app.main import create_app
    from tests.conftest import _wait_ready

    with TestClient(create_app(settings_factory())) as first:
        _wait_ready(first)
        files = batch_files(12, width=800, height=600)
        ids = [first.post("/v1/photos/batches", files=files, data=FACES_ONLY).json()["id"] for _ in range(4)]
        states = [first.get(f"/v1/jobs/{i}").json()["state"] for i in ids]
    # Leaving the block stopped the service; with 2 CPUs some jobs were still queued or running.
    assert {"queued", "running"} & set(states), states
    with TestClient(create_app(settings_factory())) as second:
        for job_id in ids:
            job = wait_final(second, job_id)
            assert job["state"] == "succeeded", job
            assert len(second.get(f"/v1/jobs/{job_id}/results/report.json").json()) == 12
            # The stop interrupted attempts: counted as restarts, never as lost workers.
            assert job["worker_losses"] == 0 and job["attempts"] == job["service_restarts"] + 1, job


@pytest.mark.slow
def test_a_job_routed_by_resource_runs_on_the_second_node():
    result = run_scenario("tests/app/cluster_scenario.py", 300)
    assert result["state"] == "succeeded"
    assert result["ran_on"] == result["second_node"] != result["head_node"]


def test_a_job_no_node_can_run_fails_with_the_reason(client_factory):
    client = client_factory(job_resources={"gpu_renderer": 1}, job_unschedulable_seconds=1.0)
    job = client.post("/v1/photos/batches", files=batch_files(1)).json()
    final = wait_final(client, job["id"], timeout=30)
    assert final["state"] == "failed"
    assert "gpu_renderer=1" in final["error"] and "sweepcast worker" in final["error"]
