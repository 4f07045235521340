"""Faults survived: each backend of a scaled-out deployment fails while jobs run, and what users saw.

    python -m benchmarks.chaos [--faults database,storage_hang,...] [--outage SECONDS]

The stack is the compose deployment's, run as processes on loopback (every part is the real server): PostgreSQL
(initdb/pg_ctl), an S3 server (moto) behind a proxy that can break it, Redis holding the Ray head's state (Ray's GCS
fault tolerance, as docker/compose.yaml sets it up), a Ray head without task CPUs, one Ray worker node, and the API
(`python -m app serve`) joined to that cluster. For each fault, while a 40-photo batch runs and a client keeps
using the API (job status, job list, a finished job's results and `/readyz` twice a second, a 2-photo upload every ~3 s) and
a viewer orbits the demo recording (reconnecting 2 s after its socket ends, as the viewer page does):

- database: PostgreSQL stopped at once (`pg_ctl -m immediate`), started again after the outage;
- storage_hang / storage_slowdown / storage_unreachable: the object store freezes (connections accepted, never
  answered), answers every request `503 SlowDown`, or refuses connections, for the outage;
- storage_full: a second API whose data folder (the file blob store) is a 64 MB tmpfs: filled to under the
  service's free-space floor (uploads, /readyz, reads of results), then filled while a batch runs so its results
  no longer fit (the job's end, its results, objects published), then freed (the time to ready, a new batch);
- ray_head: every process of the Ray head killed (SIGKILL), started again after the outage;
- slow_clients: 20 photo uploads trickling at 10 KB/s each for the outage (above the service's 1 KB/s floor, so
  they are served: none may hold the event loop or a worker);
- out_of_memory: a job that needs more memory than its node has (a 49 MP depth map upsampled with the weighted
  median filter, ~1.6 GB) beside ordinary batches, on a node whose Ray memory monitor stops tasks above 0.9 GB
  more than the machine used when the node started (out_of_memory_tight: 0.7 GB, too little for the job even
  alone; a fresh worker running the 16-photo batch alone peaks 0.27 GB over the machine's use before it, yet at
  0.5 GB Ray stopped that batch too, twice, once alone on the node: what else the machine took since the node
  started is counted against the same headroom).

Reported per fault: the answers each route gave during the fault (status counts; server errors other than 503,
connection failures and the slowest answer), whether every job accepted before, during and after it succeeded
(none lost, none failed), and the seconds from the fault's end to `/readyz` 200 and to the batch's end.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import httpx
import numpy as np

from benchmarks._report import md_table, prog, publish
from benchmarks._timing import load_note
from benchmarks.cluster import photos
from benchmarks.docker_stack import wait_for
from harness.servers import (ROOT, FaultyProxy, Unavailable, create_database, exit_on_sigterm, free_port, guarded,
                           kill_mentioning, postgres_server, stop_group)

FINAL = ("succeeded", "failed", "cancelled")
RAY = str(Path(sys.executable).parent / "ray")
FAULTS = ("database", "storage_hang", "storage_slowdown", "storage_unreachable", "storage_full", "ray_head",
          "slow_clients", "out_of_memory", "out_of_memory_tight")
OOM_HEADROOM_GB = {"out_of_memory": 0.9, "out_of_memory_tight": 0.7}
SLOW_UPLOADS = 20
SLOW_RATE = 10_000  # bytes per second each


@dataclass
class SupervisedApp:
    """The API as a service manager runs it: started again on the same port and data whenever it exits asking to
    be (``sweepcast serve``'s exit code 75, after the Ray head it used came back), as the compose file's restart
    policy does; ``restarts`` counts them."""

    base: str
    log: Path
    proc: subprocess.Popen | None = None
    restarts: int = 0
    headers: dict[str, str] = field(default_factory=dict)  # the loopback API runs without keys

    def log_tail(self, chars: int = 3000) -> str:
        return self.log.read_text(errors="replace")[-chars:] if self.log.exists() else ""


@contextlib.contextmanager
def supervised_api(env: dict[str, str], log: Path) -> Iterator[SupervisedApp]:
    port = free_port()
    app = SupervisedApp(f"http://127.0.0.1:{port}", log)
    merged = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "SWEEPCAST_FETCH_MODELS": "false", **env}
    stopping = threading.Event()

    def start() -> None:
        with open(log, "ab") as out:
            app.proc = subprocess.Popen([sys.executable, "-m", "app", "serve", "--port", str(port), "--log-level",
                                         "warning"], cwd=ROOT, env=merged, stdout=out, stderr=subprocess.STDOUT,
                                        stdin=subprocess.DEVNULL, start_new_session=True)

    def supervise() -> None:
        while not stopping.is_set():
            if app.proc.poll() == 75:
                app.restarts += 1
                start()
            stopping.wait(0.5)

    start()
    watcher = threading.Thread(target=supervise, daemon=True)
    with guarded(marker=str(log)):  # whatever ends this process, no server outlives it
        watcher.start()
        try:
            wait_for(lambda: httpx.get(f"{app.base}/readyz", timeout=2).status_code == 200, 180, "the API")
            yield app
        finally:
            stopping.set()
            watcher.join()
            stop_group(app.proc.pid, 30.0, app.proc)


def photo_files(count: int) -> list[tuple[str, tuple[str, bytes, str]]]:
    return [("files", (name, data, "image/jpeg")) for name, data in photos(count)]


class RayCluster:
    """A Ray head (its state in Redis) and worker nodes, each in its own temp folder (found and killed by it)."""

    def __init__(self, redis_port: int, folder: str) -> None:
        self.parent = folder
        self.port = free_port()
        self.address = f"127.0.0.1:{self.port}"
        self.env = {**os.environ, "RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0",
                    "RAY_gcs_rpc_server_reconnect_timeout_s": "300"}
        self.redis = f"127.0.0.1:{redis_port}"
        self.folders: list[str] = []
        self.head_folder = ""

    def _folder(self, prefix: str) -> str:
        folder = tempfile.mkdtemp(prefix=prefix, dir=self.parent)  # short: Ray's socket paths must fit 107 bytes
        self.folders.append(folder)
        return folder

    def start_head(self) -> None:
        # A new folder each time: `ray start --head` refuses a port its folder's last cluster used while other
        # nodes of this machine still name it (a check for one machine; a head container restarts alike).
        self.head_folder = self._folder("sch-")
        subprocess.run([RAY, "start", "--head", f"--port={self.port}", "--num-cpus=0", "--include-dashboard=false",
                        f"--temp-dir={self.head_folder}", "--disable-usage-stats"], check=True, capture_output=True,
                       env={**self.env, "RAY_REDIS_ADDRESS": self.redis, "RAY_external_storage_namespace": "chaos"},
                       timeout=120)

    def kill_head(self) -> None:
        kill_mentioning(self.head_folder)

    def add_node(self, cpus: int = 2, env: dict[str, str] | None = None) -> str:
        """Start a worker node; its folder (to kill it by)."""
        folder = self._folder("scn-")
        subprocess.run([RAY, "start", f"--address={self.address}", f"--num-cpus={cpus}",
                        '--resources={"sweepcast_worker": 1}', f"--temp-dir={folder}", "--disable-usage-stats"],
                       check=True, capture_output=True, env={**self.env, **(env or {})}, timeout=120)
        return folder

    def stop(self) -> None:
        for folder in self.folders:
            kill_mentioning(folder)
            shutil.rmtree(folder, ignore_errors=True)


@contextlib.contextmanager
def s3_server() -> Iterator[str]:
    """moto's S3 server on loopback; yields its host:port."""
    server = shutil.which("moto_server", path=str(Path(sys.executable).parent))
    if server is None:
        raise Unavailable("moto_server is not installed (pip install 'moto[server]')")
    port = free_port()
    proc = subprocess.Popen([server, "-H", "127.0.0.1", "-p", str(port)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        wait_for(lambda: httpx.get(f"http://127.0.0.1:{port}/moto-api/", timeout=1).status_code == 200, 30,
                   "the S3 server")
        yield f"127.0.0.1:{port}"
    finally:
        proc.kill()
        proc.wait()


@contextlib.contextmanager
def redis_server() -> Iterator[int]:
    binary = shutil.which("redis-server")
    if binary is None:
        raise Unavailable("redis-server is not installed (Debian: apt install redis-server)")
    port = free_port()
    proc = subprocess.Popen([binary, "--port", str(port), "--save", "", "--appendonly", "no"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        time.sleep(0.5)
        yield port
    finally:
        proc.kill()
        proc.wait()



class Prober:
    """A client using the API twice a second on its own thread: each route's answers, by phase."""

    def __init__(self, base: str, job_id: str, finished_id: str, headers: dict[str, str]) -> None:
        self.client = httpx.Client(base_url=base, headers=headers, timeout=120)
        self.routes: dict[str, Callable[[], httpx.Response]] = {
            "GET /v1/jobs/{id}": lambda: self.client.get(f"/v1/jobs/{job_id}"),
            "GET /v1/jobs": lambda: self.client.get("/v1/jobs", params={"limit": 5}),
            "POST /v1/photos/batches (2 photos)": lambda: self.client.post("/v1/photos/batches",
                                                                           files=photo_files(2)),
            "GET a finished job's results": lambda: self.client.get(f"/v1/jobs/{finished_id}/results/report.json"),
            "GET /readyz": lambda: self.client.get("/readyz"),
        }
        self.phase = "before"
        self.answers: list[dict[str, Any]] = []
        self.accepted: list[str] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> "Prober":
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(300)
        self.client.close()

    def _run(self) -> None:
        rounds = 0
        while not self._stop.is_set():
            rounds += 1
            for route, call in self.routes.items():
                if route.startswith("POST") and rounds % 5 != 1:  # an upload every few seconds: each is a job
                    continue
                phase, t = self.phase, time.monotonic()
                try:
                    r = call()
                    outcome: Any = r.status_code
                    if route.startswith("POST") and r.status_code == 202:
                        self.accepted.append(r.json()["id"])
                    body = r.json() if r.headers.get("content-type", "").startswith("application/json") else {}
                    code = body.get("error") if isinstance(body, dict) else None
                except httpx.HTTPError as exc:
                    outcome, code = type(exc).__name__, None
                self.answers.append({"route": route, "phase": phase, "outcome": outcome, "code": code,
                                     "seconds": time.monotonic() - t})
            self._stop.wait(0.5)

    def summary(self, phase: str) -> dict[str, Any]:
        out = {}
        for route in self.routes:
            got = [a for a in self.answers if a["route"] == route and a["phase"] == phase]
            out[route] = {
                "answers": dict(Counter(f"{a['outcome']}" + (f" {a['code']}" if a["code"] else "") for a in got)),
                "server_errors_not_503": sum(isinstance(a["outcome"], int) and a["outcome"] >= 500
                                             and a["outcome"] != 503 for a in got),
                "connection_failures": sum(not isinstance(a["outcome"], int) for a in got),
                "slowest_s": max((a["seconds"] for a in got), default=0.0),
            }
        return out


class Viewer:
    """A viewer of the demo recording behaving as the viewer page does: a viewpoint every 0.5 s (160x120); when
    its socket closes or fails, it connects again 2 s later. Frames by the prober's phase, failures, and the
    seconds from the fault's end to its first frame after it."""

    def __init__(self, base: str, prober: "Prober", headers: dict[str, str]) -> None:
        from benchmarks.streaming import demo_recording

        self.headers = headers
        with httpx.Client(base_url=base, headers=headers, timeout=30) as c:
            rig_id, recording = wait_for(lambda: demo_recording(c), 600, "the demo recording")
        self.url = f"{base.replace('http', 'ws', 1)}/v1/rigs/{rig_id}/view?source={recording['id']}"
        self.prober = prober
        self.frames: list[tuple[float, str]] = []
        self.failures: list[tuple[float, str]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> "Viewer":
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(60)

    def _run(self) -> None:
        from websockets.sync.client import connect

        from benchmarks.streaming import view_message
        from workers.streaming.framing import unpack_message

        i = 0
        while not self._stop.is_set():
            try:
                with connect(self.url, additional_headers=self.headers, max_size=None, open_timeout=10) as ws:
                    while json.loads(ws.recv(timeout=30))["type"] != "ready":
                        pass
                    while not self._stop.is_set():
                        i += 1
                        ws.send(json.dumps(view_message(i, 0.0, (160, 120))))
                        while not (isinstance(m := ws.recv(timeout=30), bytes) and unpack_message(m)[0]["id"] == i):
                            if isinstance(m, str) and json.loads(m).get("type") == "error":
                                raise RuntimeError(m)
                        self.frames.append((time.monotonic(), self.prober.phase))
                        self._stop.wait(0.5)
            except Exception as exc:  # noqa: BLE001 - whatever ended the socket, the page connects again
                self.failures.append((time.monotonic(), type(exc).__name__))
                self._stop.wait(2.0)

    def summary(self, ended: float) -> dict[str, Any]:
        after = [t for t, _ in self.frames if t >= ended]
        return {"frames": dict(Counter(phase for _, phase in self.frames)),
                "failures": dict(Counter(name for _, name in self.failures)),
                "first_frame_after_s": after[0] - ended if after else None}


def job_outcomes(base: str, ids: list[str], timeout: float, headers: dict[str, str] | None = None) -> dict[str, Any]:
    """Wait for every job to end; their states counted, and the errors of those that did not succeed."""
    states: dict[str, dict] = {}
    with httpx.Client(base_url=base, headers=headers or {}, timeout=30) as c:
        deadline = time.monotonic() + timeout
        pending = list(ids)
        while pending and time.monotonic() < deadline:
            for job_id in list(pending):
                try:
                    job = c.get(f"/v1/jobs/{job_id}").json()
                except httpx.HTTPError:
                    continue
                if job.get("state") in FINAL:
                    states[job_id] = job
                    pending.remove(job_id)
            time.sleep(1.0)
    counts = Counter(j["state"] for j in states.values())
    counts["not finished"] = len(ids) - len(states)
    return {"jobs": len(ids), "states": {k: v for k, v in counts.items() if v},
            "errors": sorted({j["error"] for j in states.values() if j["state"] != "succeeded"}),
            "attempts": sorted({j["attempts"] for j in states.values()})}


class RawClients:
    """``SLOW_UPLOADS`` clients on raw sockets, each on its own thread running ``client()``."""

    def __init__(self, base: str, headers: dict[str, str] | None = None) -> None:
        self.host, self.port = base.removeprefix("http://").split(":")
        self.header_lines = "".join(f"{k}: {v}\r\n" for k, v in (headers or {}).items())
        self._threads = [threading.Thread(target=self.client, daemon=True) for _ in range(SLOW_UPLOADS)]

    def client(self) -> None:
        raise NotImplementedError

    def begin(self) -> None:
        for t in self._threads:
            t.start()

    def end(self) -> None:
        for t in self._threads:
            t.join(120)


class SlowUploads(RawClients):
    """Photo-batch uploads, each sent at ``SLOW_RATE`` bytes per second on a raw socket (a phone on a bad link)."""

    def __init__(self, base: str, seconds: float, headers: dict[str, str] | None = None) -> None:
        super().__init__(base, headers)
        self.body_bytes = int(SLOW_RATE * seconds)
        self.statuses: list[str] = []
        self.accepted: list[str] = []

    def client(self) -> None:
        import socket

        name, jpeg = photos(1)[0]
        boundary = "chaosboundary"
        pad = max(self.body_bytes - len(jpeg), 0)  # a JPEG may carry trailing bytes: the decoder stops at EOI
        body = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"files\"; filename=\"{name}\"\r\n"
                f"Content-Type: image/jpeg\r\n\r\n").encode() + jpeg + b"\0" * pad + f"\r\n--{boundary}--\r\n".encode()
        head = (f"POST /v1/photos/batches HTTP/1.1\r\nHost: {self.host}\r\nContent-Type: multipart/form-data; "
                f"boundary={boundary}\r\nContent-Length: {len(body)}\r\n{self.header_lines}Connection: close\r\n\r\n").encode()
        try:
            with socket.create_connection((self.host, int(self.port)), timeout=120) as sock:
                sock.sendall(head)
                step = SLOW_RATE // 10
                for i in range(0, len(body), step):
                    sock.sendall(body[i:i + step])
                    time.sleep(0.1)
                answer = b""
                while chunk := sock.recv(65536):
                    answer += chunk
            status = answer.split(b" ", 2)[1].decode()
            self.statuses.append(status)
            if status == "202":
                self.accepted.append(json.loads(answer.split(b"\r\n\r\n", 1)[1])["id"])
        except OSError as exc:
            self.statuses.append(type(exc).__name__)


class StalledHeaders(RawClients):
    """Connections that send the start of a request's headers and then nothing (a slowloris): when the server
    answered and closed each, and what it answered."""

    def __init__(self, base: str) -> None:
        super().__init__(base)
        self.answers: list[str] = []
        self.closed_after_s: list[float] = []

    def client(self) -> None:
        import socket

        t = time.monotonic()
        try:
            with socket.create_connection((self.host, int(self.port)), timeout=120) as sock:
                sock.sendall(b"POST /v1/photos/batches HTTP/1.1\r\nHost: chaos\r\nContent-Type: multipart/")
                answer = b""
                while chunk := sock.recv(65536):
                    answer += chunk
            self.answers.append(answer.split(b" ", 2)[1].decode() if answer else "closed without an answer")
            self.closed_after_s.append(time.monotonic() - t)
        except OSError as exc:
            self.answers.append(type(exc).__name__)

    def summary(self) -> dict[str, Any]:
        return {"answers": dict(Counter(self.answers)),
                "closed_after_s": [min(self.closed_after_s, default=0.0), max(self.closed_after_s, default=0.0)]}


def running_batch(base: str, count: int = 40, headers: dict[str, str] | None = None) -> str:
    with httpx.Client(base_url=base, headers=headers or {}, timeout=120) as c:
        job = c.post("/v1/photos/batches", files=photo_files(count)).json()
        wait_for(lambda: c.get(f"/v1/jobs/{job['id']}").json()["progress"]["fraction"] >= 0.05, 300,
                   "the batch to make progress", interval=0.2)
    return job["id"]


def run_fault(app: SupervisedApp, finished_id: str, name: str, begin: Callable[[], None], end: Callable[[], None],
              outage_s: float, extra: Callable[[], dict[str, Any]] | None = None) -> dict[str, Any]:
    """One fault while a batch runs and a client uses the API; see the module docstring."""
    batch = running_batch(app.base, headers=app.headers)
    with Prober(app.base, batch, finished_id, app.headers) as prober, Viewer(app.base, prober, app.headers) as viewer:
        time.sleep(2.0)
        prober.phase = "during"
        begin()
        time.sleep(outage_s)
        end()
        ended = time.monotonic()
        prober.phase = "after"
        ready_s = wait_for(lambda: httpx.get(f"{app.base}/readyz", timeout=10).status_code == 200 and
                             time.monotonic() - ended, 600, f"/readyz after {name}")
        outcomes = job_outcomes(app.base, [batch], 900, app.headers)
        batch_s = time.monotonic() - ended
        time.sleep(3.0)  # the client's uploads after recovery
        wait_for(lambda: viewer.summary(ended)["first_frame_after_s"] is not None, 120, "the viewer's next frame")
        watched = viewer.summary(ended)
    accepted = job_outcomes(app.base, prober.accepted, 900, app.headers)
    print(f"{name}: ready {ready_s:.1f} s after the fault, batch {outcomes}, uploads {accepted}", flush=True)
    return {"fault": name, "outage_s": outage_s, "ready_after_s": ready_s, "batch_done_after_s": batch_s,
            "batch": outcomes, "uploads_accepted": accepted, **(extra() if extra else {}),
            "during": prober.summary("during"), "after": prober.summary("after"), "viewer": watched,
            "api_restarts": app.restarts}


def slow_clients(app: SupervisedApp, finished_id: str, outage_s: float) -> dict[str, Any]:
    """The slow_clients fault: :data:`SLOW_UPLOADS` uploads trickling for ``outage_s`` and as many connections that
    never finish their headers, while a batch runs (:func:`run_fault`)."""
    slow, stalled = SlowUploads(app.base, outage_s, app.headers), StalledHeaders(app.base)
    return run_fault(app, finished_id, "slow_clients", lambda: (slow.begin(), stalled.begin()),
                     lambda: (slow.end(), stalled.end()), 0.0, extra=lambda: {
                         "slow_uploads": {"answers": dict(Counter(slow.statuses)),
                                          **job_outcomes(app.base, slow.accepted, 900, app.headers)},
                         "stalled_headers": stalled.summary()})


def depth_bomb(side: int = 3500) -> tuple[dict[str, Any], dict[str, Any]]:
    """Multipart files and params of a one-frame 8-bit depth sequence ``side`` x ``side`` upsampled x2 with the
    weighted median filter guided by its 4:2:0 texture: ~1.6 GB at its peak on a worker (74 s on these cores)."""
    rng = np.random.default_rng(0)

    def blobs(size: int) -> np.ndarray:
        coarse = (rng.random((size // 16 + 1, size // 16 + 1)) * 255).astype(np.uint8)
        return np.kron(coarse, np.ones((16, 16), np.uint8))[:size, :size]

    out = 2 * side
    texture = np.concatenate([blobs(out).ravel(), np.full(out * out // 2, 128, np.uint8)])
    files = {"depth": ("big.yuv", blobs(side).tobytes(), "application/octet-stream"),
             "texture": ("big_texture.yuv", texture.tobytes(), "application/octet-stream")}
    return files, {"width": side, "height": side, "scale": 2, "method": "wmf"}


def out_of_memory(app: SupervisedApp) -> dict[str, Any]:
    """An oversized job beside an ordinary batch, then another batch. Ray's memory monitor may stop both; each is
    tried again alone on the node (app/dispatcher.py): the batches succeed, and the oversized job succeeds if it
    fits alone, else fails saying memory."""
    files, params = depth_bomb()
    with httpx.Client(base_url=app.base, headers=app.headers, timeout=300) as c:
        before = running_batch(app.base, 16, app.headers)
        big = c.post("/v1/depth/videos", files=files, data={"params": json.dumps(params)})
        if big.status_code != 202:
            raise SystemExit(f"the oversized job was refused: {big.status_code} {big.text}")
        big_out = job_outcomes(app.base, [big.json()["id"]], 1200, app.headers)
        after = c.post("/v1/photos/batches", files=photo_files(8)).json()["id"]
    ordinary = job_outcomes(app.base, [before, after], 900, app.headers)
    print(f"out_of_memory: oversized {big_out}, ordinary {ordinary}", flush=True)
    return {"fault": "out_of_memory", "oversized": big_out, "ordinary": ordinary, "api_restarts": app.restarts,
            "oversized_id": big.json()["id"]}


VOLUME_MB, VOLUME_MIN_FREE_MB = 64, 16


@contextlib.contextmanager
def small_volume(folder: Path) -> Iterator[Path]:
    """A ``VOLUME_MB`` tmpfs mounted at ``folder`` (needs root, as a data volume's size limit would)."""
    folder.mkdir(parents=True, exist_ok=True)
    subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={VOLUME_MB}m", "tmpfs", str(folder)], check=True)
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


def fill(volume: Path, leave_mb: float) -> None:
    """Grow the filler file on ``volume`` until ``leave_mb`` is free (0: as full as it gets)."""
    filler = volume / "filler"
    filler.touch()
    free = shutil.disk_usage(volume).free
    with open(filler, "r+b") as f:
        size = os.fstat(f.fileno()).st_size + free - int(leave_mb * 2**20)
        os.posix_fallocate(f.fileno(), 0, max(size, 1))


def _answer(r: httpx.Response) -> str:
    body = r.json() if r.headers.get("content-type", "").startswith("application/json") else {}
    return f"{r.status_code} {(body.get('error') or '') if isinstance(body, dict) else ''}".strip()


def storage_full(cluster_address: str, database_url: str, workdir: Path) -> dict[str, Any]:
    """The blob volume full: an API whose data folder (the file blob store) is a small tmpfs, filled while it
    works, then freed. Each step's answers, what became of a batch whose results no longer fit, and whether any
    of its results were published."""
    from workers.runtime import results_prefix
    from workers.storage import open_store

    out: dict[str, Any] = {"fault": "storage_full", "volume_mb": VOLUME_MB, "min_free_mb": VOLUME_MIN_FREE_MB}
    with small_volume(workdir / "volume") as volume:
        env = {"SWEEPCAST_DATA_DIR": str(volume), "SWEEPCAST_DATABASE_URL": database_url,
               "SWEEPCAST_RAY_ADDRESS": cluster_address, "RAY_AUTH_MODE": "disabled", "SWEEPCAST_DEMO_RIG": "false",
               "SWEEPCAST_MIN_FREE_STORAGE_MB": str(VOLUME_MIN_FREE_MB), "SWEEPCAST_JOB_MAX_ATTEMPTS": "2"}
        with supervised_api(env, workdir / "full.log") as app, httpx.Client(base_url=app.base, timeout=120) as c:
            before = c.post("/v1/photos/batches", files=photo_files(8)).json()["id"]
            out["before"] = job_outcomes(app.base, [before], 300)["states"]

            fill(volume, VOLUME_MIN_FREE_MB / 2)  # nearly full: under the service's floor
            out["nearly_full"] = {
                "upload": _answer(c.post("/v1/photos/batches", files=photo_files(2))),
                "readyz": _answer(r := c.get("/readyz")) + f" ({r.json()['checks']['storage'].get('detail', '')})",
                "read a result": _answer(c.get(f"/v1/jobs/{before}/results/report.json")),
                "list jobs": _answer(c.get("/v1/jobs")),
            }

            (volume / "filler").unlink()  # room for a batch's inputs, then none for its results
            fill(volume, VOLUME_MIN_FREE_MB + 12)
            r = c.post("/v1/photos/batches", files=photo_files(60))
            out["results_do_not_fit"] = {"upload": _answer(r)}
            if r.status_code == 202:
                job_id = r.json()["id"]
                wait_for(lambda: c.get(f"/v1/jobs/{job_id}").json()["state"] != "queued", 120, "the batch to start",
                         interval=0.1)
                fill(volume, 0)
                ended = job_outcomes(app.base, [job_id], 300)
                store = open_store(volume.joinpath("blobs").as_uri())
                out["results_do_not_fit"].update(
                    job=ended["states"], error="; ".join(ended["errors"])[:300],
                    results=_answer(c.get(f"/v1/jobs/{job_id}/results/report.json")),
                    objects_published=len(store.list(results_prefix(job_id))))

            (volume / "filler").unlink()
            freed = time.monotonic()
            ready_s = wait_for(lambda: c.get("/readyz").status_code == 200 and time.monotonic() - freed, 120,
                               "/readyz once space is freed", interval=0.2)
            after = c.post("/v1/photos/batches", files=photo_files(8))
            out["freed"] = {"ready_after_s": ready_s, "upload": _answer(after),
                            "job": job_outcomes(app.base, [after.json()["id"]], 300)["states"]
                            if after.status_code == 202 else {}}
            out["log_errors"] = [line for line in app.log_tail(20000).splitlines() if "Traceback" in line][:5]
    print(f"storage_full: {out}", flush=True)
    return out


def memory_threshold(extra_gb: float) -> float:
    """Ray's memory-monitor threshold (fraction of the machine) that trips ``extra_gb`` above what is used now."""
    info = {line.split(":")[0]: int(line.split()[1]) * 1024 for line in Path("/proc/meminfo").read_text().splitlines()}
    total, available = info["MemTotal"], info["MemAvailable"]
    return min((total - available + extra_gb * 2**30) / total, 0.95)


def main() -> int:
    ap = argparse.ArgumentParser(prog=prog(), description=__doc__.splitlines()[0])
    ap.add_argument("--faults", default=",".join(FAULTS),
                    help=f"comma-separated, of {', '.join(FAULTS)} (the out_of_memory ones run last)")
    ap.add_argument("--outage", type=float, default=30.0, help="seconds each fault lasts (storage_hang: twice)")
    args = ap.parse_args()
    faults = sorted((f for f in args.faults.split(",") if f), key=lambda f: f in OOM_HEADROOM_GB)
    unknown = set(faults) - set(FAULTS)
    if unknown:
        ap.error(f"unknown fault(s) {', '.join(sorted(unknown))}")
    for name in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY"):  # the S3 server takes any; set before Ray starts
        os.environ.setdefault(name, "sweepcast-chaos")
    load_before = os.getloadavg()[0]
    results: dict[str, Any] = {"faults": []}
    with exit_on_sigterm(), postgres_server() as pg, s3_server() as s3, redis_server() as redis_port, \
            FaultyProxy(s3) as proxy, tempfile.TemporaryDirectory(prefix="sweepcast-chaos-") as data:
        import boto3

        boto3.client("s3", endpoint_url=f"http://{s3}", region_name="us-east-1").create_bucket(Bucket="chaos")
        ray_folder = tempfile.mkdtemp(prefix="scc")
        cluster = RayCluster(redis_port, ray_folder)
        with guarded(marker=ray_folder):
            try:
                cluster.start_head()
                node = cluster.add_node()
                env = {"SWEEPCAST_DATA_DIR": data, "SWEEPCAST_DATABASE_URL": create_database(pg.url, "chaos"),
                       "SWEEPCAST_STORAGE_URL": f"s3://chaos/sc?endpoint_url=http://{proxy.address}&region=us-east-1",
                       "SWEEPCAST_RAY_ADDRESS": cluster.address, "RAY_AUTH_MODE": "disabled",
                       "RAY_gcs_rpc_server_reconnect_timeout_s": "300",
                       "SWEEPCAST_JOB_MAX_ATTEMPTS": "2"}
                with supervised_api(env, Path(data) / "serve.log") as app:
                    with httpx.Client(base_url=app.base, timeout=120) as c:
                        finished = c.post("/v1/photos/batches", files=photo_files(4)).json()["id"]
                    job_outcomes(app.base, [finished], 300)
                    breaks: dict[str, tuple[Callable[[], None], Callable[[], None], float]] = {
                        "database": (pg.stop, pg.start, args.outage),
                        "storage_hang": (lambda: proxy.set("hang"), lambda: proxy.set("pass"), 2 * args.outage),
                        "storage_slowdown": (lambda: proxy.set("slowdown"), lambda: proxy.set("pass"), args.outage),
                        "storage_unreachable": (lambda: proxy.set("refuse"), lambda: proxy.set("pass"), args.outage),
                        "ray_head": (cluster.kill_head, cluster.start_head, args.outage),
                    }
                    for fault in faults:
                        started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
                        if fault in OOM_HEADROOM_GB:  # on a node of its own, the last faults
                            kill_mentioning(node)
                            headroom = OOM_HEADROOM_GB[fault]
                            node = cluster.add_node(env={
                                "RAY_memory_usage_threshold": f"{memory_threshold(headroom):.3f}",
                                "RAY_memory_monitor_refresh_ms": "100"})
                            results["faults"].append({**out_of_memory(app), "fault": fault, "headroom_gb": headroom})
                        elif fault == "storage_full":  # an API of its own whose data volume fills
                            results["faults"].append(storage_full(cluster.address, create_database(pg.url, "full"),
                                                                  Path(data)))
                        elif fault == "slow_clients":
                            results["faults"].append(slow_clients(app, finished, args.outage))
                        else:
                            results["faults"].append(run_fault(app, finished, fault, *breaks[fault]))
                        results["faults"][-1]["measured"] = started
                    results["log_tail"] = app.log_tail(4000)
            finally:
                cluster.stop()
                shutil.rmtree(ray_folder, ignore_errors=True)
    results["load_average"] = {"before": load_before, "after": os.getloadavg()[0]}
    results["faults"] = kept_faults(faults) + results["faults"]
    publish("chaos", results, markdown(results))
    return 0


def kept_faults(run: list[str]) -> list[dict[str, Any]]:
    """The previous results of the faults not run this time (``--faults`` a subset), in the usual order."""
    from benchmarks._report import RESULTS_DIR

    previous = RESULTS_DIR / "chaos.json"
    if not previous.exists():
        return []
    kept = [f for f in json.loads(previous.read_text()).get("faults", []) if f["fault"] not in run]
    return sorted(kept, key=lambda f: FAULTS.index(f["fault"]))


def _viewer(v: dict[str, Any] | None) -> str:
    if v is None:
        return "-"
    frames = ", ".join(f"{k} {n}" for k, n in v["frames"].items())
    failures = f"; socket ended x{sum(v['failures'].values())}" if v["failures"] else ""
    return f"frames {frames}{failures}; first frame {v['first_frame_after_s']:.1f} s after the fault's end"


def _answers(summary: dict[str, Any]) -> str:
    return "; ".join(f"{route.split(' (')[0]}: " + ", ".join(f"{k} x{v}" for k, v in s["answers"].items())
                     for route, s in summary.items())


FAULT_COLUMNS = ["measured", "fault", "outage s", "answers during the fault", "jobs", "5xx other than 503 / dropped",
                 "ready / batch done after (s)", "a viewer (reconnecting as the page does)", "API restarts so far"]


def fault_table(faults: list[dict[str, Any]]) -> str:
    """One row per fault (:func:`run_fault`'s record, or storage_full's and out_of_memory's own)."""
    rows = []
    for f in faults:
        if f["fault"] == "storage_full":
            n, x, fr = f["nearly_full"], f["results_do_not_fit"], f["freed"]
            rows.append([f.get("measured", ""), f"storage_full ({f['volume_mb']} MB tmpfs, floor "
                         f"{f['min_free_mb']} MB)", "-",
                         "nearly full: " + ", ".join(f"{k} {v}" for k, v in n.items()),
                         f"before: {f['before']}; a 60-photo batch whose results no longer fit: upload {x['upload']}, "
                         f"job {x.get('job')} ({x.get('error', '')}), its results {x.get('results')}, "
                         f"{x.get('objects_published')} objects published; after freeing: upload {fr['upload']}, "
                         f"job {fr['job']}", f"{len(f['log_errors'])} tracebacks in the log",
                         f"{fr['ready_after_s']:.1f} / -", "-", "-"])
            continue
        if f["fault"] == "out_of_memory_container":
            o, s = f["oversized"], f["ordinary"]
            limits = ", ".join(f"{mb} MB" for mb in f["limits_mb"].values())
            rows.append([f.get("measured", ""), f"out_of_memory (worker containers limited to {limits}: their use + "
                         f"{f.get('headroom_mb', 1000):.0f} MB)", "-", f"oversized job: {o['states']}, attempts {o['attempts']} "
                         f"({'; '.join(o['errors'])[:300]})", f"ordinary batches: {s['states']}",
                         f"workers OOM-killed: {sum(f['oom_killed'].values())}, restarted "
                         f"{sum(f['worker_restarts'].values())} times; the dispatcher: "
                         + "; ".join(f.get("dispatcher_log", [])), "-", "-",
                         f["api_restarts"]])
            continue
        if f["fault"] in OOM_HEADROOM_GB:
            o, s = f["oversized"], f["ordinary"]
            rows.append([f.get("measured", ""), f"{f['fault']} (node stops tasks {f.get('headroom_gb', 0.9)} GB "
                         "over the machine's use)", "-", f"oversized job: {o['states']} ({'; '.join(o['errors'])[:300]})",
                         f"ordinary batch: {s['states']}", "-", "-", "-", f["api_restarts"]])
            continue
        during = f["during"]
        bad = sum(s["server_errors_not_503"] + s["connection_failures"] for s in during.values())
        slowest = max(s["slowest_s"] for s in during.values())
        slow = f.get("slow_uploads")
        slow_text = (f"; the {SLOW_UPLOADS} uploads at {SLOW_RATE // 1000} KB/s answered {slow['answers']}, their "
                     f"jobs {slow['states']}" if slow else "")
        if "stalled_headers" in f:
            h = f["stalled_headers"]
            slow_text += (f"; {SLOW_UPLOADS} connections that never finished their headers answered {h['answers']}, "
                          f"closed {h['closed_after_s'][0]:.1f}-{h['closed_after_s'][1]:.1f} s after opening")
        outage = f"{f['outage_s']:.0f}" if f["outage_s"] else "(the uploads' length)"
        rows.append([f.get("measured", ""), f["fault"], outage, _answers(during),
                     f"batch {f['batch']['states']}, attempts {f['batch']['attempts']}; client uploads "
                     f"{f['uploads_accepted']['states']}{slow_text}",
                     f"{bad} (slowest answer {slowest:.1f} s)", f"{f['ready_after_s']:.1f} / {f['batch_done_after_s']:.1f}",
                     _viewer(f.get("viewer")), f["api_restarts"]])
    return md_table(FAULT_COLUMNS, rows)


def fault_section(intro: str, r: dict[str, Any]) -> str:
    """A chaos section's body: ``intro``, the table of ``r["faults"]`` and the run's load note."""
    la = r["load_average"]
    return "\n".join([intro, "", fault_table(r["faults"]), "", load_note(la["before"], la["after"])])


def markdown(r: dict[str, Any]) -> str:
    return fault_section(
        "The compose deployment's parts as processes on loopback (PostgreSQL, moto's S3 behind a breakable proxy, "
        "Redis for the Ray head's state, a Ray head and one 2-CPU worker node, one API); each fault while a 40-photo "
        "batch runs and a client calls five routes twice a second. Columns: what the client's routes answered during "
        "the fault (status and error code x count); what became of the jobs (the batch, and every upload the client "
        "got 202 for, before, during or after the fault); answers that were neither a success nor a 503 with a "
        "reason (server errors, dropped connections); seconds from the fault's end to `/readyz` 200 and to the "
        "batch's end; the viewer's frames by phase and its first frame after the fault's end; how many times the API process had stopped to be started again (it does once a lost Ray head is "
        "back: app/ray_watch.py; the harness restarts it as the compose file's restart policy does).", r)


if __name__ == "__main__":
    sys.exit(main())
