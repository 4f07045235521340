"""The service while a backend it depends on is down: clear answers meanwhile, nothing lost, back by itself."""
from __future__ import annotations

import datetime as dt
import time

import pytest

from harness.photos import FACES_ONLY, batch_files
from tests.app.test_jobs_e2e import wait_final
from harness.servers import create_database

KEY = "outage-test-key"
AUTH = {"Authorization": f"Bearer {KEY}"}


def _started(client, job_id: str, timeout: float = 60.0) -> None:
    with client.websocket_connect(f"/v1/jobs/{job_id}/events") as ws:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            event = ws.receive_json()
            if event["type"] == "started" or event.get("state") == "running":
                return
            assert event["type"] != "final", event
    raise AssertionError("the job never started")


def _stored_inputs(data_dir) -> list[str]:
    return sorted(p.name for p in (data_dir / "blobs" / "inputs").glob("*")) if (data_dir / "blobs" / "inputs").exists() else []


def test_a_database_outage_answers_503_and_the_running_job_finishes_after_it(client_factory, settings_factory,
                                                                             stoppable_postgres):
    url = create_database(stoppable_postgres.url, "outage")
    client = client_factory(database_url=url, api_keys=[KEY])
    client.headers.update(AUTH)
    data_dir = settings_factory().data_dir
    r = client.post("/v1/photos/batches", files=batch_files(12, width=1024, height=768), data=FACES_ONLY)
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    _started(client, job_id)
    inputs_before = _stored_inputs(data_dir)

    stoppable_postgres.stop()
    try:
        got = client.get(f"/v1/jobs/{job_id}")  # the route's own read
        assert got.status_code == 503 and got.json()["error"] == "database_unavailable", got.text
        assert int(got.headers["retry-after"]) > 0
        other = client.get("/v1/jobs", headers={"Authorization": "Bearer not-a-service-key"})  # the key lookup
        assert other.status_code == 503 and other.json()["error"] == "database_unavailable", other.text
        refused = client.post("/v1/photos/batches", files=batch_files(2), data=FACES_ONLY)
        assert refused.status_code == 503 and refused.json()["error"] == "database_unavailable", refused.text
        assert _stored_inputs(data_dir) == inputs_before  # nothing kept of the refused upload
        ready = client.get("/readyz")
        assert ready.status_code == 503 and ready.json()["checks"]["database"]["ok"] is False
        time.sleep(3.0)  # longer than the job needs to run: it ends during the outage
    finally:
        restarted = dt.datetime.now(dt.timezone.utc)
        stoppable_postgres.start()

    job = wait_final(client, job_id)
    assert job["state"] == "succeeded", job
    assert (job["attempts"], job["worker_losses"], job["service_restarts"]) == (1, 0, 0), job
    assert dt.datetime.fromisoformat(job["finished_at"]) >= restarted  # its end was recorded once the database was back
    assert len(client.get(f"/v1/jobs/{job_id}/results/report.json").json()) == 12
    listed = client.get("/v1/jobs").json()["jobs"]
    assert [j["id"] for j in listed] == [job_id]  # the refused batch left no row
    assert client.get("/readyz").status_code == 200



@pytest.fixture
def faulty_s3(s3_endpoint):
    """A fresh bucket on the loopback S3 server, reached through a proxy the test can break."""
    import uuid

    import boto3

    from harness.servers import FaultyProxy

    bucket = f"b{uuid.uuid4().hex[:12]}"
    boto3.client("s3", endpoint_url=s3_endpoint, region_name="us-east-1").create_bucket(Bucket=bucket)
    with FaultyProxy(s3_endpoint.removeprefix("http://")) as proxy:
        # a store that failed is tried again after 1 s (5 s by default): the job and /readyz notice its return sooner
        yield proxy, f"s3://{bucket}/sweepcast?endpoint_url=http://{proxy.address}&region=us-east-1&retry_after=1"


@pytest.mark.parametrize("fault", ["refuse", "slowdown"])
def test_an_object_store_outage_answers_503_and_the_running_job_publishes_after_it(client_factory, faulty_s3, fault):
    proxy, url = faulty_s3
    client = client_factory(storage_url=url)
    done = client.post("/v1/photos/batches", files=batch_files(2), data=FACES_ONLY).json()
    assert wait_final(client, done["id"])["state"] == "succeeded"
    r = client.post("/v1/photos/batches", files=batch_files(12, width=1024, height=768), data=FACES_ONLY)
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    _started(client, job_id)

    proxy.set(fault)
    try:
        refused = client.post("/v1/photos/batches", files=batch_files(2), data=FACES_ONLY)
        assert refused.status_code == 503 and refused.json()["error"] == "storage_unavailable", refused.text
        assert int(refused.headers["retry-after"]) > 0
        result = client.get(f"/v1/jobs/{done['id']}/results/report.json")
        assert result.status_code == 503 and result.json()["error"] == "storage_unavailable", result.text
        ready = client.get("/readyz")
        assert ready.status_code == 503 and ready.json()["checks"]["storage"]["ok"] is False, ready.text
        assert client.get(f"/v1/jobs/{job_id}").status_code == 200  # the job table still answers
        time.sleep(3.0)  # longer than the job needs to run: it publishes during the outage, and waits
    finally:
        proxy.set("pass")

    job = wait_final(client, job_id)
    assert job["state"] == "succeeded", job
    assert (job["attempts"], job["worker_losses"]) == (1, 0), job
    assert len(client.get(f"/v1/jobs/{job_id}/results/report.json").json()) == 12
    listed = client.get("/v1/jobs").json()["jobs"]
    assert sorted(j["id"] for j in listed) == sorted([done["id"], job_id])  # the refused batch left no row
    deadline = time.monotonic() + 30
    while client.get("/readyz").status_code != 200:  # the breaker lets a request through within seconds
        assert time.monotonic() < deadline, client.get("/readyz").json()
        time.sleep(0.5)


def test_a_frozen_store_fails_a_fetch_within_its_shorter_budget_while_a_write_keeps_its_own(faulty_s3):
    """A client reading a result from a frozen store gets its 503 after the fetch budget (3 s x 2 by default),
    not after the writes' (10 s x 3), which stays long for a real S3's slow multipart completions."""
    from workers.storage import StoreUnavailable, open_store, storage_unavailable

    proxy, url = faulty_s3
    store = open_store(url + "&read_timeout=2.5&max_attempts=1&fetch_timeout=0.3&fetch_attempts=2")
    store.put("jobs/a/report.json", b"{}")
    proxy.set("hang")
    try:
        started = time.monotonic()
        with pytest.raises(Exception) as fetch:
            store.read("jobs/a/report.json")
        fetch_s = time.monotonic() - started
        assert storage_unavailable(fetch.value) and not isinstance(fetch.value, StoreUnavailable), fetch.value
        assert fetch_s < 2.5, fetch_s  # gave up before a single write timeout would have
        time.sleep(1.1)  # the store is left alone for retry_after (1 s) after a failure
        started = time.monotonic()
        with pytest.raises(Exception) as write:
            store.put("jobs/a/other", b"x")
        assert storage_unavailable(write.value) and not isinstance(write.value, StoreUnavailable), write.value
        assert time.monotonic() - started >= 2.5  # the write waited out its own read timeout
    finally:
        proxy.set("pass")
    time.sleep(1.1)
    assert store.read("jobs/a/report.json") == b"{}"


def test_readiness_says_when_no_live_node_offers_a_cpu():
    """Every worker gone: still ready (uploads are taken, jobs wait for a worker), but the probe says why nothing
    runs; no live node at all: not ready."""
    from app.raycluster import describe_nodes

    head = {"Alive": True, "Resources": {"memory": 1e9}}  # `ray start --head --num-cpus=0`: no CPU key at all
    api = {"Alive": True, "Resources": {"CPU": 0.0, "node:10.0.0.3": 1.0}}
    worker = {"Alive": True, "Resources": {"CPU": 2.0, "sweepcast_worker": 1.0}}
    assert describe_nodes([head, api, worker]) == (True, "3 Ray node(s), 2 CPU(s) for jobs")
    assert describe_nodes([head, api, {**worker, "Alive": False}]) == (
        True, "2 Ray node(s), none with CPUs: jobs wait until a worker joins")
    assert describe_nodes([{**head, "Alive": False}]) == (False, "no live Ray node")
