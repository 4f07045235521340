"""Run by test_survey_cluster in a fresh process: a survey through the service on a local Ray cluster of a head
(the API only, no CPU for jobs) and two worker nodes of one CPU each, split into two submodels.

Prints one JSON line: the job's state, its stages' tasks per node, the nodes' ids, the map's coverage and the
submodels' alignment.
"""
from __future__ import annotations

import io
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
from harness.scenarios import wait_job, wait_ready  # noqa: E402
from harness.surveys import small_survey_zip  # noqa: E402

PARAMS = {"max_features": 600, "dense_planes": 32, "submodel_photos": 4}


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        data = small_survey_zip(Path(tmp) / "stills")
        cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 0})
        nodes = [cluster.add_node(num_cpus=1) for _ in range(2)]
        cluster.wait_for_nodes()
        try:
            settings = Settings(data_dir=Path(tmp) / "data", ray_address=cluster.address, demo_rig=False,
                                fetch_models=False)
            with TestClient(create_app(settings)) as client:
                deadline = time.monotonic() + 240
                wait_ready(client, deadline)
                job = client.post("/v1/reconstructions", files={"media": ("survey.zip", io.BytesIO(data))},
                                  data={"params": json.dumps(PARAMS)}).json()
                if "id" not in job:
                    raise SystemExit(f"refused: {job}")
                state = wait_job(client, job["id"], deadline, poll_s=0.2)
                report = (client.get(f"/v1/jobs/{job['id']}/results/report.json").json()
                          if state["state"] == "succeeded" else {})
                ortho = (client.get(f"/v1/jobs/{job['id']}/results/orthophoto.tif").content
                         if state["state"] == "succeeded" else b"")
        finally:
            import ray

            ray.shutdown()
            cluster.shutdown()
    stages = report.get("stages", {}).get("stages", {})
    print(json.dumps({
        "state": state["state"], "error": state.get("error"),
        "tasks_per_node": {k: v.get("tasks_per_node", {}) for k, v in stages.items()},
        "worker_nodes": [n.node_id for n in nodes],
        "coverage": report.get("mapping", {}).get("coverage"),
        "registered": report.get("frames", {}).get("registered"),
        "submodels": report.get("survey", {}).get("plan", {}).get("submodels"),
        "alignment": report.get("survey", {}).get("alignment"),
        "orthophoto_bytes": len(ortho),
    }))
    return 0


if __name__ == "__main__":
    sys.exit(main())
