"""Scale-out figures: orientation batch throughput on 1 and 2 Ray nodes, and the time from submit to
the first progress event with SQLite versus PostgreSQL.

    python -m benchmarks.cluster [--quick]

Every run starts its own servers on loopback: a Ray cluster with `ray start` (a head without task
CPUs plus 1 or 2 worker nodes of one CPU each), a throw-away PostgreSQL, and the API as a
subprocess (`python -m app serve`). On one 2-core machine the nodes share the same cores, so two
nodes can at best use both cores; the figure shows the dispatch path scales, not more hardware.
"""
from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import httpx
from websockets.sync.client import connect

from benchmarks._report import md_table, prog, publish
from harness.servers import create_database, exit_on_sigterm, ray_cluster, serve_app, temp_postgres
from workers.common.datasets import dataset

ROOT = Path(__file__).resolve().parents[1]


def photos(count: int) -> list[tuple[str, bytes]]:
    """Real face photos (cycled) when the benchmark data is present, else generated ones."""
    folder = dataset("faces", "dev")
    files = sorted(p for p in folder.rglob("*") if p.suffix.lower() in (".jpg", ".jpeg")) if folder else []
    if files:
        return [(files[i % len(files)].name, files[i % len(files)].read_bytes()) for i in range(count)]
    from harness.photos import noise_jpeg

    return [(f"generated-{i}.jpg", noise_jpeg(i, 1024, 768)) for i in range(count)]


@contextmanager
def api(env_extra: dict[str, str]) -> Iterator[str]:
    with tempfile.TemporaryDirectory(prefix="sweepcast-bench-", ignore_cleanup_errors=True) as data, \
            serve_app({"SWEEPCAST_DATA_DIR": data, "RAY_AUTH_MODE": "disabled", **env_extra},
                      args=("--log-level", "warning"), ready_timeout=120) as app:
        yield app.base


def wait_done(base: str, job_ids: list[str], timeout: float = 1800) -> None:
    deadline = time.monotonic() + timeout
    pending = set(job_ids)
    while pending:
        for job_id in list(pending):
            state = httpx.get(f"{base}/v1/jobs/{job_id}", timeout=10).json()["state"]
            if state in ("succeeded", "failed", "cancelled"):
                if state != "succeeded":
                    raise RuntimeError(f"job {job_id} {state}")
                pending.discard(job_id)
        if time.monotonic() > deadline:
            raise RuntimeError("jobs did not finish in time")
        time.sleep(0.2)


def throughput(nodes: int, batches: int, per_batch: int) -> dict[str, float]:
    """Photos/s for ``batches`` concurrent batch jobs of ``per_batch`` photos on ``nodes`` worker nodes."""
    images = photos(per_batch)
    with ray_cluster(worker_nodes=nodes, cpus_per_node=1) as address:
        with api({"SWEEPCAST_RAY_ADDRESS": address}) as base:
            files = [("files", (name, data, "image/jpeg")) for name, data in images]
            warm = httpx.post(f"{base}/v1/photos/batches", files=files[:2], timeout=120).json()["id"]
            wait_done(base, [warm])  # workers started, cascades loaded
            start = time.perf_counter()
            ids = [httpx.post(f"{base}/v1/photos/batches", files=files, timeout=120).json()["id"]
                   for _ in range(batches)]
            wait_done(base, ids)
            seconds = time.perf_counter() - start
    return {"photos": batches * per_batch, "seconds": seconds, "photos_per_s": batches * per_batch / seconds}


def first_progress_ms(database_url: str | None, repeats: int) -> dict[str, float]:
    """Median and p95 milliseconds from POST to the first event from the job's worker on its socket
    (``started``, sent when the attempt begins, or a progress event, whichever comes first)."""
    env = {"SWEEPCAST_DATABASE_URL": database_url} if database_url else {}
    (name, data), = photos(1)
    samples = []
    with api(env) as base:
        ws_base = base.replace("http", "ws")
        for i in range(repeats + 1):
            start = time.perf_counter()
            job = httpx.post(f"{base}/v1/photos/batches", files=[("files", (name, data, "image/jpeg"))],
                             timeout=60).json()
            with connect(f"{ws_base}/v1/jobs/{job['id']}/events") as ws:
                while True:
                    event = json.loads(ws.recv(timeout=60))
                    if event["type"] in ("started", "progress", "final"):
                        break
            if i:  # the first one warms a worker up
                samples.append((time.perf_counter() - start) * 1000)
    samples.sort()
    return {"median_ms": statistics.median(samples), "p95_ms": samples[int(0.95 * (len(samples) - 1))],
            "repeats": repeats}


def main() -> None:
    parser = argparse.ArgumentParser(prog=prog(), description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer photos and repeats")
    args = parser.parse_args()
    batches, per_batch, repeats = (2, 8, 5) if args.quick else (4, 30, 20)

    results: dict = {"throughput": {}, "first_progress": {}}
    for nodes in (1, 2):
        print(f"throughput with {nodes} node(s)...", flush=True)
        results["throughput"][f"{nodes}_nodes"] = throughput(nodes, batches, per_batch)
    print("submit -> first progress, SQLite...", flush=True)
    results["first_progress"]["sqlite"] = first_progress_ms(None, repeats)
    print("submit -> first progress, PostgreSQL...", flush=True)
    with temp_postgres() as server:
        results["first_progress"]["postgresql"] = first_progress_ms(create_database(server, "bench"), repeats)

    t = results["throughput"]
    f = results["first_progress"]
    markdown = "\n\n".join([
        f"Orientation batches: {batches} concurrent jobs of {per_batch} photos "
        f"({'real face photos' if dataset('faces', 'dev') else 'generated photos'}), Ray cluster started with "
        "`ray start` (head without task CPUs + worker nodes of 1 CPU each, all on this machine).",
        md_table(["worker nodes", "photos", "seconds", "photos/s", "vs 1 node"],
                 [[n, t[f"{n}_nodes"]["photos"], t[f"{n}_nodes"]["seconds"], t[f"{n}_nodes"]["photos_per_s"],
                   t[f"{n}_nodes"]["photos_per_s"] / t["1_nodes"]["photos_per_s"]] for n in (1, 2)]),
        f"Submit (POST of one photo) to the first event from its worker (`started`) on the job socket, "
        f"{repeats} jobs after a warm-up:",
        md_table(["job table", "median ms", "p95 ms"],
                 [[name, f[name]["median_ms"], f[name]["p95_ms"]] for name in ("sqlite", "postgresql")]),
    ])
    publish("cluster", results, markdown)
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    with exit_on_sigterm():  # SIGTERM unwinds the server blocks (API, Ray nodes, PostgreSQL), which stop them
        main()
