"""Run by test_scale_out in a fresh process: a two-node Ray cluster and a job routed to node 2.

Prints one JSON line: the node the job ran on and the ids of both nodes.
"""
from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
os.environ.setdefault("RAY_AUTH_MODE", "disabled")
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from fastapi.testclient import TestClient  # noqa: E402
from ray.cluster_utils import Cluster  # noqa: E402

from app.main import create_app  # noqa: E402
from app.settings import Settings  # noqa: E402
from harness.photos import FACES_ONLY, batch_files  # noqa: E402
from harness.scenarios import wait_job, wait_ready  # noqa: E402


def main() -> int:
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    second = cluster.add_node(num_cpus=1, resources={"sweepcast_second_node": 1})
    cluster.wait_for_nodes()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            # no demo rig (its recording would be rendered on node 2 first) and no model download: only the job
            settings = Settings(data_dir=Path(tmp), ray_address=cluster.address, demo_rig=False, fetch_models=False,
                                job_resources={"sweepcast_second_node": 1})
            with TestClient(create_app(settings)) as client:
                deadline = time.monotonic() + 60
                wait_ready(client, deadline)
                job = client.post("/v1/photos/batches", files=batch_files(2), data=FACES_ONLY).json()
                state = wait_job(client, job["id"], deadline)
        print(json.dumps({
            "state": state["state"],
            "ran_on": state["result"]["worker"]["node_id"] if state["result"] else None,
            "second_node": second.node_id,
            "head_node": cluster.head_node.node_id,
        }))
    finally:
        import ray

        ray.shutdown()
        cluster.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
