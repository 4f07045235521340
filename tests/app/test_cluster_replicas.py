"""Scale-out on one machine: a real Ray cluster (`ray start`), two API replicas, PostgreSQL and S3.

A client watching a job on replica A sees the progress of a job submitted through replica B; the
node running the job loses its raylet mid-job and the job finishes on the other node.
"""
from __future__ import annotations

import contextlib
import json
import os
import signal
from pathlib import Path

import httpx
import pytest
from websockets.sync.client import connect

from harness.photos import FACES_ONLY, batch_files
from harness.servers import ray_cluster, serve_app



def parent_pid(pid: int) -> int:
    stat = Path(f"/proc/{pid}/stat").read_text()
    return int(stat[stat.rindex(")") + 2:].split()[1])


@pytest.fixture
def cluster():
    with ray_cluster(worker_nodes=2) as address:
        yield address


@pytest.mark.slow
def test_two_replicas_share_jobs_and_survive_a_lost_node(cluster, postgres_url, s3_url, tmp_path):
    with contextlib.ExitStack() as replicas:
        apps = [replicas.enter_context(serve_app({
            "RAY_AUTH_MODE": "disabled", "SWEEPCAST_RAY_ADDRESS": cluster, "SWEEPCAST_DATABASE_URL": postgres_url,
            "SWEEPCAST_STORAGE_URL": s3_url, "SWEEPCAST_DATA_DIR": str(tmp_path / name),
            "SWEEPCAST_JOB_LEASE_SECONDS": "5", "SWEEPCAST_JOB_RESOURCES": '{"sweepcast_worker": 1}',
            "SWEEPCAST_DEMO_RIG": "false"},  # its recording would be rendered on a worker node beside the job
            wait=False)) for name in ("a", "b")]  # both start at once, then both must get ready
        for app in apps:
            app.wait_ready(90)
        base_a, base_b = (app.base for app in apps)

        # still running when its node dies after the first photo; small photos: both attempts take seconds
        files = [("files", f) for _, f in batch_files(16, width=800, height=600)]
        job = httpx.post(f"{base_b}/v1/photos/batches", files=files, data=FACES_ONLY, timeout=60).json()
        ws_b = connect(f"{base_b.replace('http', 'ws')}/v1/jobs/{job['id']}/events")
        ws_a = connect(f"{base_a.replace('http', 'ws')}/v1/jobs/{job['id']}/events")
        while (event := json.loads(ws_b.recv(timeout=120)))["type"] != "started":
            assert event["type"] in ("snapshot", "progress"), event
        first_node = event["node_id"]
        raylet = parent_pid(event["pid"])
        while json.loads(ws_b.recv(timeout=120))["type"] != "progress":
            pass
        # the node running the job goes away mid-job, with every process on it: a worker left running without its
        # raylet may still finish a short job and hand its result straight to the API (its owner), one attempt
        os.kill(raylet, signal.SIGKILL)
        os.kill(event["pid"], signal.SIGKILL)

        seen_on_a = []
        while (event := json.loads(ws_a.recv(timeout=240)))["type"] != "final":
            seen_on_a.append(event)
        final = event["job"]
        assert final["state"] == "succeeded", final
        assert final["attempts"] >= 2
        assert final["result"]["worker"]["node_id"] != first_node
        assert any(e["type"] == "progress" for e in seen_on_a), seen_on_a
        report = httpx.get(f"{base_a}/v1/jobs/{job['id']}/results/report.json").json()
        assert len(report) == 16


def test_a_replica_with_ray_join_node_joins_the_cluster_as_a_node_without_cpus(tmp_path):
    """The image's API role: ``sweepcast serve`` starts this machine's node (`ray start --address --num-cpus=0`) while
    it imports itself, then connects through it."""
    import shutil
    import tempfile

    from harness.servers import guarded, kill_mentioning

    with ray_cluster(worker_nodes=1) as address:
        own = tempfile.mkdtemp(prefix="scjoin-")  # the joined node's folder, by which its processes are found
        try:
            with guarded(marker=own), serve_app({
                    "RAY_AUTH_MODE": "disabled", "RAY_TMPDIR": own, "SWEEPCAST_RAY_ADDRESS": address,
                    "SWEEPCAST_RAY_JOIN_NODE": "true", "SWEEPCAST_DATA_DIR": str(tmp_path / "data"),
                    "SWEEPCAST_DEMO_RIG": "false"}, log=tmp_path / "serve.log", ready_timeout=120) as app:
                ready = httpx.get(f"{app.base}/readyz", timeout=10).json()["checks"]["ray"]
                # the head, the worker and this replica's; only the worker's CPU runs jobs
                assert ready["detail"] == "3 Ray node(s), 1 CPU(s) for jobs", ready
                assert "joining the Ray cluster at" in app.log_tail(20000)
        finally:
            kill_mentioning(own)
            shutil.rmtree(own, ignore_errors=True)
