"""Photos per second of the orientation engine: in this process (threads, OpenCV's own pool on and off, CPU per photo)
and over HTTP on a served app (concurrent clients, every process's CPU counted, ``/healthz`` probed meanwhile)."""
from __future__ import annotations

import concurrent.futures
import statistics
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from benchmarks._timing import settle_server
from harness.proc import cpu_seconds, machine_busy_seconds, tree_cpu_seconds
from harness.servers import CHECKOUT_KERNEL_CACHE, serve_app
from workers.orientation.decode import decode_gray
from workers.orientation.detect import OrientationDetector
from workers.orientation.orient import analyze


def rate(fn, items: list[bytes], threads: int, repeats: int) -> float:
    """Median items per second of ``fn`` over ``repeats`` passes with ``threads`` workers."""
    rates = []
    with concurrent.futures.ThreadPoolExecutor(threads) as pool:
        list(pool.map(fn, items[:2 * threads]))  # untimed: builds each thread's detectors
        for _ in range(repeats):
            start = time.perf_counter()
            list(pool.map(fn, items))
            rates.append(len(items) / (time.perf_counter() - start))
    return statistics.median(rates)

def cpu_ms_per_photo(fn, items: list[bytes]) -> float:
    """Median CPU time (ms, this thread, OpenCV single-threaded) of ``fn`` per item: unlike wall time it
    barely depends on other processes, so ``2000 / cpu_ms`` estimates photos/s on 2 idle cores."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    fn(items[0])
    times = []
    for item in items:
        start = time.thread_time()
        fn(item)
        times.append(1000 * (time.thread_time() - start))
    cv2.setNumThreads(threads)
    return statistics.median(times)

def run_engine_speed(large: list[bytes], detectors: dict[str, OrientationDetector], repeats: int) -> dict:
    """Photos per second of ``analyze`` in this process: 1 and 2 worker threads, with OpenCV's own
    thread pool on (default) and off (``cv2.setNumThreads(1)``, one core per photo)."""
    default_threads = cv2.getNumThreads()
    out: dict = {"decode_only_photos_per_s_1thread": rate(decode_gray, large, 1, repeats)}
    for name, detector in detectors.items():
        out[name] = {"cpu_ms_per_photo": cpu_ms_per_photo(lambda d: analyze(d, detector), large)}
        for cv_threads, tag in ((default_threads, ""), (1, "_cv1")):
            cv2.setNumThreads(cv_threads)
            for k in (1, 2):
                cpu = time.process_time()
                out[name][f"photos_per_s_{k}thread{tag}"] = rate(lambda d: analyze(d, detector), large, k, repeats)
                if k == 2 and tag == "_cv1":  # CPU per photo with two photos at a time, as a served app runs them
                    done = min(len(large), 2 * k) + repeats * len(large)
                    out[name]["cpu_ms_per_photo_2thread"] = 1000 * (time.process_time() - cpu) / done
        cv2.setNumThreads(default_threads)
        print(f"engine {name}: {out[name]}", flush=True)
    return out

def run_http_speed(large: list[bytes], yunet: Path | None, clients: int | list[int], repeats: int,
                   text: bool = True) -> dict:
    """Photos per second through ``POST /v1/photos/orientation`` of a real server subprocess; with a list
    of client counts, one result per count (same server), each with ``/healthz`` latency meanwhile.
    ``text`` False: the server's text cue off (the faces alone). The server's start-up work is left to finish
    first (:func:`_settle`): its numba kernels come from the checkout's cache (``sweepcast-data/cache/numba``), as in a
    service that has started before, so no compile shares the cores with the photos."""
    import httpx

    with tempfile.TemporaryDirectory(prefix="sweepcast-bench-") as tmp:
        # fetching stays off (serve_app): the paper run must not pick up a fetched model
        env = {"SWEEPCAST_DATA_DIR": tmp, "SWEEPCAST_ORIENTATION_YUNET_MODEL": str(yunet) if yunet else None,
               "SWEEPCAST_NUMBA_CACHE_DIR": str(CHECKOUT_KERNEL_CACHE)}
        if not text:
            env["SWEEPCAST_ORIENTATION_TEXT"] = "false"
        try:
            with serve_app(env, log=Path(tmp) / "server.log") as app:
                settle = _settle(app.base, app.proc.pid)
                if isinstance(clients, int):
                    return {**_post_all(app.base, app.proc.pid, large, clients, repeats, httpx), "settle": settle}
                return {str(n): {**_post_all(app.base, app.proc.pid, large, n, repeats, httpx, healthz=True),
                                 "settle": settle} for n in clients}
        except RuntimeError as exc:
            return {"error": str(exc)}

def _settle(base: str, pid: int) -> dict:
    """Wait until the served app's start-up work is done (:func:`benchmarks._timing.settle_server`: the server's
    process tree below 0.1 core over one second)."""
    return settle_server(base, pid, lambda p: tree_cpu_seconds(p, reaped=True), interval_s=1.0, timeout_s=300.0)

def _multipart(data: bytes, boundary: str) -> bytes:
    """A ``multipart/form-data`` body with ``data`` as the part ``file`` (photo.jpg, image/jpeg)."""
    head = (f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="photo.jpg"\r\n'
            "Content-Type: image/jpeg\r\n\r\n").encode()
    return head + data + f"\r\n--{boundary}--\r\n".encode()

def _post_all(base: str, pid: int, large: list[bytes], clients: int, repeats: int, httpx,
              healthz: bool = False) -> dict:
    """``repeats`` timed passes (after a warm-up pass) of ``clients`` threads posting the photos, each pass
    ``max(2 * len(large), 2 * clients)`` requests (the photos in turn), so that every client has requests
    in flight. Request bodies are built once, before the clock: the clients share the machine's cores
    with the server, and their CPU (this process), the server's (its own process; its process tree) and
    the whole machine's are counted over the timed passes."""
    url = f"{base}/v1/photos/orientation"
    probe = _HealthProbe(f"{base}/healthz", httpx) if healthz else None
    local = __import__("threading").local()
    latencies: list[float] = []
    decisions: dict[str, int] = {}
    boundary = "sweepcast-bench-boundary"
    headers = {"content-type": f"multipart/form-data; boundary={boundary}"}
    bodies = [_multipart(data, boundary) for data in large]
    per_pass = max(2 * len(bodies), 2 * clients)
    work = [bodies[i % len(bodies)] for i in range(per_pass)]

    def post(body: bytes) -> None:
        client = getattr(local, "client", None)
        if client is None:
            client = local.client = httpx.Client(timeout=300.0)
        start = time.perf_counter()
        response = client.post(url, content=body, headers=headers)
        latencies.append(time.perf_counter() - start)
        if response.status_code != 200:
            raise RuntimeError(f"POST {url} -> {response.status_code}: {response.text[:300]}")
        decision = response.json()["decision"]
        decisions[decision] = decisions.get(decision, 0) + 1

    rates = []
    with concurrent.futures.ThreadPoolExecutor(clients) as pool:
        # the first pass is the warm-up (each server thread builds its detector, the connections open): timed
        # and reported apart; photos_per_s is the median of the passes after it (steady state)
        start = time.perf_counter()
        list(pool.map(post, work))
        first = len(work) / (time.perf_counter() - start)
        latencies.clear()
        decisions.clear()
        if probe is not None:
            probe.start()
        cpu0 = (cpu_seconds(pid, reaped=True), tree_cpu_seconds(pid, reaped=True), time.process_time(), machine_busy_seconds(),
                time.perf_counter())
        for _ in range(repeats):
            start = time.perf_counter()
            list(pool.map(post, work))
            rates.append(len(work) / (time.perf_counter() - start))
        cpu1 = (cpu_seconds(pid, reaped=True), tree_cpu_seconds(pid, reaped=True), time.process_time(), machine_busy_seconds(),
                time.perf_counter())
    health = probe.stop() if probe is not None else None
    photos = len(work) * repeats
    server, tree, client, machine, wall = (b - a for a, b in zip(cpu0, cpu1))
    cpu = {"server_cpu_ms_per_photo": 1000 * server / photos, "server_tree_cpu_ms_per_photo": 1000 * tree / photos,
           "client_cpu_ms_per_photo": 1000 * client / photos, "machine_busy_cores": machine / wall,
           "other_cpu_ms_per_photo": 1000 * (machine - tree - client) / photos}
    return {"photos_per_s": statistics.median(rates), "rates": rates, "first_pass_photos_per_s": first,
            "clients": clients, "requests_per_pass": per_pass, "median_latency_ms": 1000 * statistics.median(latencies),
            "decisions": decisions, **cpu, **({"healthz": health} if health else {})}

class _HealthProbe:
    """``GET /healthz`` every 50 ms on its own connection while the photos are posted: latency p50/p99 (ms)."""

    def __init__(self, url: str, httpx) -> None:
        import threading

        self.url, self.httpx = url, httpx
        self.times: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        with self.httpx.Client(timeout=30.0) as client:
            while not self._stop.is_set():
                t = time.perf_counter()
                client.get(self.url).raise_for_status()
                self.times.append(1000 * (time.perf_counter() - t))
                self._stop.wait(0.05)

    def stop(self) -> dict:
        self._stop.set()
        self._thread.join()
        return {"probes": len(self.times), "p50_ms": float(np.percentile(self.times, 50)),
                "p99_ms": float(np.percentile(self.times, 99)), "max_ms": float(max(self.times))}
