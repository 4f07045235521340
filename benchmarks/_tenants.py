"""The tenants section of benchmarks/robustness.py (``--only tenants``): cross-key probes over every resource operation
and socket, the quota probes, and what owners and keys cost (the owner-filtered list of 10,000 jobs, the key
lookup per request)."""
from __future__ import annotations

import json
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

import httpx
from websockets.sync.client import connect

from benchmarks._report import md_table
from harness.photos import noise_jpeg
from harness.tenancy import SOCKETS, bearer, probe, refused_as_missing
from harness.servers import ServedApp, serve_app
from harness.takes import make_take, rig_json, zip_bytes

ADMIN = "tenants-admin-key"


def _key(c: httpx.Client, name: str, **extra: Any) -> tuple[str, str]:
    r = c.post("/v1/keys", json={"name": name, **extra}, headers=bearer(ADMIN))
    r.raise_for_status()
    return r.json()["id"], r.json()["secret"]


def _wait_job(c: httpx.Client, job_id: str, secret: str, timeout: float = 300) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = c.get(f"/v1/jobs/{job_id}", headers=bearer(secret)).json()
        if job["state"] in ("succeeded", "failed", "cancelled"):
            return job
        time.sleep(0.2)
    raise TimeoutError(f"job {job_id} still {job['state']}")


def _alice_resources(c: httpx.Client, alice: str) -> dict[str, str]:
    """One resource of each kind, finished (so that the owner's own calls reach results, frames and reviews)."""
    a = bearer(alice)
    take = make_take()
    rig_id = c.post("/v1/rigs", files={"files": ("rig.json", rig_json(take.rig))}, headers=a).json()["id"]
    rec = c.post(f"/v1/rigs/{rig_id}/recordings", files={"archive": ("take.zip", zip_bytes(take))},
                 data={"params": '{"fps": 5}'}, headers=a).json()
    batch = c.post("/v1/photos/batches", files=[("files", ("a.jpg", noise_jpeg(1), "image/jpeg"))], headers=a).json()
    model = c.post("/v1/face-models", data={"params": '{"source": "synthetic"}'}, headers=a).json()
    for job_id in (rec["id"], batch["id"], model["id"]):
        _wait_job(c, job_id, alice)
    return {"job_id": batch["id"], "model_id": model["id"], "rig_id": rig_id, "recording_id": rec["id"],
            "index": "0", "name": "report.json", "frame": "0"}


def _socket_probe(base: str, path: str, secret: str) -> str:
    url = base.replace("http", "ws", 1) + path + ("&" if "?" in path else "?") + f"access_token={secret}"
    with connect(url, open_timeout=10) as ws:
        message = json.loads(ws.recv(timeout=10))
    return message.get("error") or message.get("detail") or message.get("type")


def _blob_files(data_dir: str) -> int:
    return sum(1 for p in (Path(data_dir) / "blobs").rglob("*") if p.is_file())


def _quota_probes(app: ServedApp, c: httpx.Client, data_dir: str) -> dict[str, Any]:
    _, small = _key(c, "small", quota={"stored_bytes": 60_000, "uploads_per_minute": 6})
    s = bearer(small)
    out: dict[str, Any] = {}
    first = c.post("/v1/photos/batches", files=[("files", ("a.jpg", noise_jpeg(1), "image/jpeg"))], headers=s)
    blobs, jobs = _blob_files(data_dir), len(c.get("/v1/jobs", headers=s).json()["jobs"])
    over = c.post("/v1/photos/batches", headers=s,
                  files=[("files", (f"{i}.jpg", noise_jpeg(i), "image/jpeg")) for i in range(2, 8)])
    out["storage"] = {"first": first.status_code, "status": over.status_code, "error": over.json()["error"],
                      "blob_files_unchanged": _blob_files(data_dir) == blobs,
                      "jobs_unchanged": len(c.get("/v1/jobs", headers=s).json()["jobs"]) == jobs}
    _, busy = _key(c, "busy", quota={"active_jobs": 1})
    b = bearer(busy)
    second = c.post("/v1/photos/batches", files=[("files", ("b.jpg", noise_jpeg(9), "image/jpeg"))], headers=b)
    third = c.post("/v1/photos/batches", files=[("files", ("c.jpg", noise_jpeg(10), "image/jpeg"))], headers=b)
    out["active_jobs"] = {"statuses": [second.status_code, third.status_code], "error": third.json().get("error"),
                          "retry_after": third.headers.get("retry-after")}
    statuses = [c.post("/v1/photos/orientation", files={"file": ("a.jpg", noise_jpeg(1), "image/jpeg")},
                       headers=s) for _ in range(5)]
    out["upload_rate"] = {"statuses": [r.status_code for r in statuses], "error": statuses[-1].json().get("error"),
                          "retry_after": statuses[-1].headers.get("retry-after")}
    _, viewer = _key(c, "viewer", quota={"viewer_sessions": 1})
    own_rig = c.post("/v1/rigs", files={"files": ("rig.json", rig_json(make_take().rig))}, headers=bearer(viewer))
    url = app.base.replace("http", "ws", 1) + f"/v1/rigs/{own_rig.json()['id']}/view?render=browser&source=live"
    with connect(f"{url}&access_token={viewer}", open_timeout=10) as ws:
        first_type = json.loads(ws.recv(timeout=10))["type"]
        with connect(f"{url}&access_token={viewer}", open_timeout=10) as refused:
            second_error = json.loads(refused.recv(timeout=10)).get("error")
    out["viewer_sessions"] = {"first": first_type, "second": second_error}
    out["usage"] = c.get("/v1/keys/me", headers=s).json()
    return out


def _median_us(fn: Callable[[], Any], n: int) -> float:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e6


def _http_lookups(c: httpx.Client, secrets: dict[str, str], n: int) -> dict[str, float]:
    """Median ms of a request that reaches a route (a 404 job) with each key, the keys taking turns."""
    times: dict[str, list[float]] = {name: [] for name in secrets}
    for _ in range(n):
        for name, secret in secrets.items():
            t0 = time.perf_counter()
            c.get("/v1/jobs/no-such-job", headers=bearer(secret))
            times[name].append(time.perf_counter() - t0)
    return {name: statistics.median(t) * 1e3 for name, t in times.items()}


def owner_list_costs(jobs_total: int = 10_000, keys: int = 10, n: int = 300) -> dict[str, Any]:
    """In one process on SQLite: list and usage of one key's jobs among ``jobs_total`` of ``keys`` keys, against
    the unfiltered list an admin gets; the query plan says whether the index serves it."""
    from sqlalchemy import text

    from app.jobstore import JobStore

    with tempfile.TemporaryDirectory() as folder:
        store = JobStore(f"sqlite:///{folder}/jobs.db")
        with store.engine.begin() as conn:
            conn.execute(text(
                "INSERT INTO jobs (id, kind, params, inputs, input_meta, state, progress, stage, attempts, "
                "worker_losses, service_restarts, created_at, updated_at, created_by, stored_bytes) VALUES "
                "(:id, 'orientation.batch', '{}', '{}', '{}', :state, 1.0, 'done', 1, 0, 0, :at, :at, :by, 1000)"),
                [{"id": f"job-{i:06d}", "state": "succeeded" if i % 10 else "queued",
                  "at": f"2026-11-28 {i // 3600 % 24:02d}:{i // 60 % 60:02d}:{i % 60:02d}.{i:06d}",
                  "by": f"key-{i % keys}"} for i in range(jobs_total)])
        with store.engine.connect() as conn:
            plan = [r[-1] for r in conn.execute(text(
                "EXPLAIN QUERY PLAN SELECT * FROM jobs WHERE created_by = 'key-3' ORDER BY created_at DESC, id DESC "
                "LIMIT 50"))]
            usage_plan = [r[-1] for r in conn.execute(text(
                "EXPLAIN QUERY PLAN SELECT sum(stored_bytes), count(*) FROM jobs WHERE created_by = 'key-3'"))]
        own = _median_us(lambda: store.list(limit=50, created_by="key-3"), n)
        everything = _median_us(lambda: store.list(limit=50), n)
        usage = _median_us(lambda: store.usage("key-3"), n)
        store.close()
    return {"jobs": jobs_total, "keys": keys, "own_list_us": own, "admin_list_us": everything, "usage_us": usage,
            "plan": plan, "usage_plan": usage_plan}


def lookup_costs(n: int = 2000) -> dict[str, Any]:
    """In one process on SQLite: the principal of a request from the service's own key against a managed key's
    (one indexed query on the key's hash, every request: a revocation holds at once)."""
    from app.auth import Authenticator
    from app.jobstore import JobStore
    from app.keys import KeyStore

    with tempfile.TemporaryDirectory() as folder:
        jobs = JobStore(f"sqlite:///{folder}/jobs.db")
        keys = KeyStore(jobs.engine)
        for i in range(100):
            keys.create(f"user-{i}")
        _, secret = keys.create("measured")
        auth = Authenticator(["env-key"], keys)
        env = _median_us(lambda: auth.resolve("env-key"), n)
        managed = _median_us(lambda: auth.resolve(secret), n)
        wrong = _median_us(lambda: auth.resolve("sck_not-a-key"), n)
        jobs.close()
    return {"env_key_us": env, "managed_key_us": managed, "unknown_key_us": wrong, "keys_in_table": 101}


def tenants(quick: bool) -> dict[str, Any]:
    data_dir = tempfile.mkdtemp(prefix="sc-tenants-")
    env = {"SWEEPCAST_DATA_DIR": data_dir, "SWEEPCAST_API_KEYS": ADMIN, "SWEEPCAST_DEMO_RIG": "false",
           "SWEEPCAST_DATABASE_URL": None, "SWEEPCAST_STORAGE_URL": None, "SWEEPCAST_RAY_ADDRESS": None}
    results: dict[str, Any] = {}
    with serve_app(env, log=Path(data_dir) / "api.log") as app:
        c = httpx.Client(base_url=app.base, timeout=120)
        _, alice = _key(c, "alice")
        _, bob = _key(c, "bob")
        ids = _alice_resources(c, alice)
        doc = c.get("/openapi.json").json()
        rows = probe(c, doc, ids, bob, alice)
        sockets = {path: _socket_probe(app.base, path.format(**ids), bob) for path in SOCKETS}
        results["cross_key"] = {"operations": rows, "sockets": sockets,
                                "all_404": all(map(refused_as_missing, rows)),
                                "sockets_refused": all(v in ("rig_not_found", f"no job with id {ids['job_id']!r}")
                                                       for v in sockets.values())}
        results["quotas"] = _quota_probes(app, c, data_dir)
        n = 100 if quick else 500
        _, managed = _key(c, "lookup", quota={"uploads_per_minute": 10**6})
        results["http_lookup_ms"] = {**_http_lookups(c, {"env_key": ADMIN, "managed_key": managed}, n), "requests": n}
    results["owner_list"] = owner_list_costs(n=100 if quick else 500)
    results["key_lookup"] = lookup_costs(500 if quick else 3000)
    return results


def markdown(r: dict[str, Any]) -> str:
    ck = r["cross_key"]
    parts = [f"### Cross-key probes (user key Bob against user key Alice's finished photo batch, face model, rig and "
             f"recording: every resource operation of the OpenAPI document, and every socket)\n\n"
             f"{len(ck['operations'])} operations, **all 404 as for a missing resource: "
             f"{'yes' if ck['all_404'] else 'NO'}**; sockets refused as missing: "
             f"{'yes' if ck['sockets_refused'] else 'NO'}.\n\n" + md_table(
                 ["operation", "Bob", "error", "Alice"],
                 [[row["operation"], row["status"], row["error"], row.get("owner_status", "(not deleted)")]
                  for row in ck["operations"]]
                 + [[f"socket {path}", "closed", why, ""] for path, why in ck["sockets"].items()])]
    q = r["quotas"]
    parts.append("### Quota probes (a user key with stored_bytes 60,000 and uploads_per_minute 6; one with "
                 "active_jobs 1; one with viewer_sessions 1)\n\n" + md_table(
                     ["quota", "what was sent", "answer", "afterwards"],
                     [["stored bytes", "a 1-photo batch, then a 6-photo batch past the limit",
                       f"{q['storage']['first']}, then {q['storage']['status']} {q['storage']['error']}",
                       f"no new job: {q['storage']['jobs_unchanged']}, no stored file: "
                       f"{q['storage']['blob_files_unchanged']}"],
                      ["active jobs", "two batches at once",
                       f"{q['active_jobs']['statuses']}, {q['active_jobs']['error']}",
                       f"Retry-After {q['active_jobs']['retry_after']}"],
                      ["uploads per minute", "5 more uploads (7 in all)",
                       f"{q['upload_rate']['statuses']}, {q['upload_rate']['error']}",
                       f"Retry-After {q['upload_rate']['retry_after']}"],
                      ["viewer sessions", "two viewer sockets", f"{q['viewer_sessions']['first']}, then "
                       f"{q['viewer_sessions']['second']}", ""]]))
    ol, kl, hl = r["owner_list"], r["key_lookup"], r["http_lookup_ms"]
    parts.append("### What owners and keys cost\n\n" + md_table(
        ["measure", "median"],
        [[f"list of one key's newest 50 jobs among {ol['jobs']:,} of {ol['keys']} keys (SQLite)",
          f"{ol['own_list_us']:.0f} µs"],
         [f"an admin's newest 50 of the {ol['jobs']:,} (no owner filter)", f"{ol['admin_list_us']:.0f} µs"],
         ["one key's usage (bytes stored, active jobs) among them", f"{ol['usage_us']:.0f} µs"],
         ["principal of the service's own key (in process)", f"{kl['env_key_us']:.1f} µs"],
         [f"principal of a managed key, one indexed query ({kl['keys_in_table']} keys)", f"{kl['managed_key_us']:.0f} µs"],
         ["an unknown key (refused)", f"{kl['unknown_key_us']:.0f} µs"],
         [f"HTTP request with the service's own key (404 route, {hl['requests']} requests each, keys taking turns)",
          f"{hl['env_key']:.2f} ms"],
         ["the same with a managed key", f"{hl['managed_key']:.2f} ms"]])
        + f"\n\nQuery plans: the list `{'; '.join(ol['plan'])}`; the usage `{'; '.join(ol['usage_plan'])}`.")
    return "\n\n".join(parts)
