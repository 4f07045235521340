"""The same service on the scaled-out backends: PostgreSQL job table and S3 object storage."""
from __future__ import annotations

import json

import numpy as np

from harness.photos import batch_files
from tests.app.test_jobs_e2e import wait_final


def test_jobs_run_with_postgresql_and_s3(client_factory, postgres_url, s3_url):
    client = client_factory(database_url=postgres_url, storage_url=s3_url)
    frames = np.zeros((3, 16, 16), np.uint8)
    frames[:, 4:12, 4:12] = 200
    r = client.post("/v1/depth/videos", files={"depth": ("seq.yuv", frames.tobytes(), "application/octet-stream")},
                    data={"params": json.dumps({"width": 16, "height": 16, "scale": 2})})
    assert r.status_code == 202, r.text
    job = wait_final(client, r.json()["id"])
    assert job["state"] == "succeeded", job
    assert len(client.get(f"/v1/jobs/{job['id']}/results/filtered.yuv").content) == 3 * 32 * 32

    batch = client.post("/v1/photos/batches", files=batch_files(3, corrupt_at=1)).json()
    done = wait_final(client, batch["id"])
    assert done["state"] == "succeeded"
    entries = client.get(f"/v1/jobs/{batch['id']}/results/report.json").json()
    assert [bool(e.get("error")) for e in entries] == [False, True, False]
    assert client.delete(f"/v1/jobs/{batch['id']}").status_code == 204
    assert client.get(f"/v1/jobs/{batch['id']}").status_code == 404
