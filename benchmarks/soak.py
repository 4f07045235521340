"""An hour of mixed load: does the service stay as it was at the start?

    python -m benchmarks.soak [--minutes 60] [--warmup-minutes 10]
    python -m benchmarks.soak --base http://127.0.0.1:8000 --base http://127.0.0.1:8001 \
        --podman-project sweepcast-verify --name soak_compose    # a running compose stack (docker/verify-stack.sh)

Starts the service as ``make serve`` runs it (``sweepcast serve`` on the embedded default: local Ray, SQLite and
a data folder, here a temporary one; the kernels from the user's cache), or uses the running service at
``--base`` (each replica's URL; the key from ``SWEEPCAST_API_KEYS``, as docker/.env sets it), waits for the demo
recording, and then for ``--minutes`` a bounded load generator uses it the way its users do, all at once (the
photo organiser and the live source on the first replica, reconstructions on the last, viewers taking turns):

- a photo organiser: a batch of 8 photos every 30 s, its state polled each second until it ends, then its report
  and the job list read;
- 4 viewers orbiting the demo recording over the view socket (320x240, 48 planes, the paper's weighting), each at
  2 frames per second, stepping through the recording's frames; each viewer leaves and comes back every 5 minutes;
- a 36-frame drone reconstruction every 3 minutes (a synthetic flight, intrinsics given), its manifest read;
- live ingest: frame sets of the demo rig's 10 cameras pushed to its live socket at 5 per second, each acked;
- ``/readyz`` every 5 s.

Every answer is recorded (route, status or the exception, seconds), every job's end state, and every 15 s the
resident memory, threads and open files of every process of the service (the API, Ray's processes and its
workers: the server's process and all its descendants; on a compose stack, every process of its containers).
Reported: 5xx answers and connection failures, jobs
lost (never ended) or failed, each process's growth of memory, threads and files from the end of the warm-up to
the end, and each route's p99 per 10-minute window against its first ten minutes. Plots of memory and latency
over the run: ``benchmarks/results/soak_*.png``.
"""
from __future__ import annotations

import argparse
import asyncio
import datetime as dt
import json
import os
import statistics
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Awaitable, Callable

import httpx
import numpy as np
import scipy.stats
import websockets

from harness.proc import descendants, status, status_mb
from benchmarks._report import RESULTS_DIR, md_table, publish, shown_path
from benchmarks._timing import load_average
from benchmarks.chaos import photo_files
from benchmarks.coldstart import make_flight
from benchmarks.docker_stack import project_containers
from benchmarks.streaming import demo_recording, frame_reply, frame_set_message, live_frame_sets
from harness.servers import exit_on_sigterm, serve_app

FINAL = ("succeeded", "failed", "cancelled")
BATCH_PHOTOS, BATCH_EVERY_S = 8, 30.0
VIEWERS, VIEWER_FPS, VIEWER_SESSION_S, VIEW_SIZE, VIEW_PLANES = 4, 2.0, 300.0, (320, 240), 48
RECONSTRUCT_EVERY_S = 180.0
LIVE_RATE = 5.0
READY_EVERY_S, SAMPLE_EVERY_S = 5.0, 15.0
WINDOW_S = 600.0


class Log:
    """What the load generator saw: one row per answer, one per job, one per process sample."""

    def __init__(self) -> None:
        self.t0 = time.monotonic()
        self.answers: list[tuple[float, str, Any, float]] = []  # (t, route, status or exception name, seconds)
        self.jobs: dict[str, dict[str, Any]] = {}  # id -> kind, accepted at, state, seconds, error
        self.samples: list[dict[str, Any]] = []

    def now(self) -> float:
        return time.monotonic() - self.t0

    async def call(self, route: str, request: Awaitable[httpx.Response]) -> httpx.Response | None:
        t = time.monotonic()
        try:
            r = await request
        except (httpx.HTTPError, OSError) as exc:
            self.answers.append((t - self.t0, route, type(exc).__name__, time.monotonic() - t))
            return None
        self.answers.append((t - self.t0, route, r.status_code, time.monotonic() - t))
        return r

    def note(self, route: str, started: float, outcome: Any) -> None:
        self.answers.append((started - self.t0, route, outcome, time.monotonic() - started))


async def until(stop: asyncio.Event, seconds: float) -> None:
    """Sleep ``seconds`` or until the run stops."""
    try:
        await asyncio.wait_for(stop.wait(), max(0.0, seconds))
    except asyncio.TimeoutError:
        pass


async def follow_job(log: Log, http: httpx.AsyncClient, job_id: str, kind: str, stop: asyncio.Event,
                     every: float, read: str | None) -> None:
    """Poll a job until it ends (going on after the run's end, for at most 10 min), then read ``read``."""
    job = log.jobs[job_id]
    deadline = time.monotonic() + 600 if stop.is_set() else None
    while deadline is None or time.monotonic() < deadline:
        r = await log.call("GET /v1/jobs/{id}", http.get(f"/v1/jobs/{job_id}"))
        if r is not None and r.status_code == 200 and r.json()["state"] in FINAL:
            body = r.json()
            job.update(state=body["state"], seconds=log.now() - job["accepted_at"], error=body.get("error"))
            if body["state"] == "succeeded" and read:
                await log.call(f"GET {kind} results", http.get(f"/v1/jobs/{job_id}/results/{read}"))
            return
        await asyncio.sleep(every)
        if deadline is None and stop.is_set():
            deadline = time.monotonic() + 600


async def photo_organiser(log: Log, http: httpx.AsyncClient, stop: asyncio.Event) -> None:
    files = photo_files(BATCH_PHOTOS)
    while not stop.is_set():
        t = time.monotonic()
        r = await log.call("POST /v1/photos/batches", http.post("/v1/photos/batches", files=files))
        if r is not None and r.status_code == 202:
            job_id = r.json()["id"]
            log.jobs[job_id] = {"kind": "photo batch", "accepted_at": log.now(), "state": "queued"}
            await follow_job(log, http, job_id, "batch", stop, 1.0, "report.json")
            await log.call("GET /v1/jobs", http.get("/v1/jobs", params={"limit": 20}))
        await until(stop, BATCH_EVERY_S - (time.monotonic() - t))


async def reconstructions(log: Log, http: httpx.AsyncClient, flight: tuple[Path, dict], stop: asyncio.Event) -> None:
    video = flight[0].read_bytes()
    params = json.dumps({**flight[1], "max_features": 1000})
    await until(stop, 60.0)
    while not stop.is_set():
        t = time.monotonic()
        r = await log.call("POST /v1/reconstructions",
                           http.post("/v1/reconstructions", files={"media": ("flight.mp4", video, "video/mp4")},
                                     data={"params": params}))
        if r is not None and r.status_code == 202:
            job_id = r.json()["id"]
            log.jobs[job_id] = {"kind": "reconstruction", "accepted_at": log.now(), "state": "queued"}
            await follow_job(log, http, job_id, "reconstruction", stop, 2.0, "report.json")
        await until(stop, RECONSTRUCT_EVERY_S - (time.monotonic() - t))


def view_message(i: int, phase: float, frames: int) -> dict:
    azimuth = -40.0 + (phase + 2.0 * i) % 80.0
    return {"type": "view", "id": i, "orbit": {"azimuth": azimuth, "elevation": 10.0 * np.sin(i / 15.0)},
            "width": VIEW_SIZE[0], "height": VIEW_SIZE[1], "planes": VIEW_PLANES, "method": "kojima",
            "frame": i % frames, "quality": 80}


HEADERS: dict[str, str] = {}
"""The API key's header for every request and socket (empty for the embedded default, which needs none)."""


async def viewer(log: Log, url: str, frames: int, phase: float, stop: asyncio.Event) -> None:
    """One viewer orbiting at ``VIEWER_FPS``; a new session every ``VIEWER_SESSION_S``."""
    i = 0
    while not stop.is_set():
        t = time.monotonic()
        try:
            async with websockets.connect(url, max_size=None, open_timeout=60, additional_headers=HEADERS) as ws:
                while json.loads(await ws.recv())["type"] != "ready":
                    pass
                log.note("WS view: connect to ready", t, 101)
                session_end = time.monotonic() + VIEWER_SESSION_S
                while not stop.is_set() and time.monotonic() < session_end:
                    i += 1
                    sent = time.monotonic()
                    await ws.send(json.dumps(view_message(i, phase, frames)))
                    await asyncio.wait_for(frame_reply(ws, i), 60)
                    log.note("WS view: viewpoint to frame", sent, 200)
                    await until(stop, 1.0 / VIEWER_FPS - (time.monotonic() - sent))
        except (OSError, asyncio.TimeoutError, websockets.WebSocketException, RuntimeError) as exc:
            log.note("WS view: viewpoint to frame", t, type(exc).__name__)
            await until(stop, 1.0)


async def live_ingest(log: Log, url: str, background: list[bytes], sets: list[list[bytes]],
                      stop: asyncio.Event) -> None:
    """Frame sets at ``LIVE_RATE`` per second, each waiting for its ack; reconnects after a failure."""
    seq = 0
    while not stop.is_set():
        t = time.monotonic()
        try:
            async with websockets.connect(url, max_size=None, open_timeout=60, additional_headers=HEADERS) as ws:
                json.loads(await ws.recv())
                seq += 1
                await ws.send(frame_set_message(background, seq, background=True))
                await ws.recv()
                t0 = time.monotonic()
                while not stop.is_set():
                    seq += 1
                    sent = time.monotonic()
                    await ws.send(frame_set_message(sets[seq % len(sets)], seq))
                    reply = json.loads(await asyncio.wait_for(ws.recv(), 60))
                    log.note("WS live: frame set to ack", sent, 200 if reply.get("type") == "ack" else reply.get("type"))
                    t0 += 1.0 / LIVE_RATE
                    await until(stop, t0 - time.monotonic())
        except (OSError, asyncio.TimeoutError, websockets.WebSocketException) as exc:
            log.note("WS live: frame set to ack", t, type(exc).__name__)
            await until(stop, 1.0)


async def readiness(log: Log, http: httpx.AsyncClient, stop: asyncio.Event) -> None:
    while not stop.is_set():
        await log.call("GET /readyz", http.get("/readyz"))
        await until(stop, READY_EVERY_S)


# --- the service's processes ----------------------------------------------------------------------
def process_sample(pid: int) -> dict[str, Any] | None:
    """Resident memory (MB) and the shared memory in it, threads and open files of one process, and its title (Ray
    names its workers by the task they run)."""
    try:
        title = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").strip()
        files = len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None
    if not (fields := status(pid)):
        return None
    return {"pid": pid, "title": title[:120], "rss_mb": status_mb(pid, "VmRSS", fields),
            "shared_mb": status_mb(pid, "RssShmem", fields), "threads": int(fields["Threads"]), "files": files}


def role(title: str, prefix: str = "") -> str:
    """A short name for a process of the service from its command line (after ``prefix``: its container)."""
    return f"{prefix}: {_role(title)}" if prefix else _role(title)


def _role(title: str) -> str:
    if "app serve" in title or "sweepcast serve" in title:
        return "API"
    for name in ("gcs_server", "raylet", "dashboard", "log_monitor", "monitor.py", "runtime_env", "dashboard_agent"):
        if name in title:
            return name.replace(".py", "")
    if title.startswith("ray::"):
        return title.split()[0]
    return Path(title.split()[0]).name if title else "?"


def podman_roots(project: str) -> dict[int, str]:
    """The main process of each running container of a compose project, by container name."""
    names = project_containers(project)
    pids = subprocess.run(["podman", "inspect", "--format", "{{.State.Pid}}", *names], capture_output=True,
                          text=True, check=True).stdout.split()
    return {int(pid): name.removeprefix(f"{project}_") for name, pid in zip(names, pids)}


def sampler(log: Log, roots: Callable[[], dict[int, str]], stop: threading.Event) -> None:
    """Every ``SAMPLE_EVERY_S``: each process under ``roots()`` (pid -> a prefix for its role, e.g. a container)."""
    while not stop.is_set():
        procs = []
        for root, prefix in roots().items():
            for pid in descendants(root):
                if (sample := process_sample(pid)) is not None:
                    procs.append({**sample, "prefix": prefix})
        log.samples.append({"t": log.now(), "load": load_average(2), "processes": procs})
        stop.wait(SAMPLE_EVERY_S)


# --- the run --------------------------------------------------------------------------------------
async def load(log: Log, bases: list[str], rig_id: str, recording: dict, flight: tuple[Path, dict],
               live: tuple[list[bytes], list[list[bytes]]], seconds: float) -> None:
    stop = asyncio.Event()
    sockets = [base.replace("http", "ws", 1) for base in bases]
    view = f"/v1/rigs/{rig_id}/view?source={recording['id']}"
    async with httpx.AsyncClient(base_url=bases[0], timeout=120, headers=HEADERS) as first, \
            httpx.AsyncClient(base_url=bases[-1], timeout=120, headers=HEADERS) as last:
        tasks = [asyncio.create_task(photo_organiser(log, first, stop)),
                 asyncio.create_task(reconstructions(log, last, flight, stop)),
                 asyncio.create_task(live_ingest(log, f"{sockets[0]}/v1/rigs/{rig_id}/live", *live, stop)),
                 asyncio.create_task(readiness(log, first, stop)),
                 *(asyncio.create_task(viewer(log, sockets[k % len(sockets)] + view, recording["frames"], 20.0 * k,
                                              stop)) for k in range(VIEWERS))]
        await until(stop, seconds)
        stop.set()
        await asyncio.gather(*tasks)  # jobs still running are followed to their end (10 min at most)


def soak(bases: list[str], roots: Callable[[], dict[int, str]], minutes: float, workdir: Path) -> Log:
    """The load on the service at ``bases`` for ``minutes``, sampling the processes under ``roots()``."""
    from workers.sweep.rig_io import rig_from_dict

    flight = make_flight(workdir)
    with httpx.Client(base_url=bases[0], timeout=60, headers=HEADERS) as http:
        deadline = time.monotonic() + 900
        while not (found := demo_recording(http)) and time.monotonic() < deadline:
            time.sleep(1.0)
        if not found:
            raise SystemExit("no demo recording after 15 min")
        rig_id, recording = found
        rig = rig_from_dict(http.get(f"/v1/rigs/{rig_id}").json()["calibration"])
    live = live_frame_sets(rig, 12)
    log = Log()
    stop = threading.Event()
    watcher = threading.Thread(target=sampler, args=(log, roots, stop), daemon=True)
    watcher.start()
    try:
        asyncio.run(load(log, bases, rig_id, recording, flight, live, 60.0 * minutes))
    finally:
        stop.set()
        watcher.join()
    return log


def error_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if "Traceback" in line or "ERROR" in line]


def podman_log_errors(project: str, since: dt.datetime) -> list[str]:
    """The error lines every container of the compose project logged since ``since`` (UTC; the soak's start: not
    what a fault run just before it provoked)."""
    out = []
    for name in podman_roots(project).values():
        logs = subprocess.run(["podman", "logs", "--since", since.strftime("%Y-%m-%dT%H:%M:%SZ"), f"{project}_{name}"],
                              capture_output=True, text=True)
        out += [f"{name}: {line}" for line in error_lines(logs.stdout + logs.stderr)]
    return out


def run(minutes: float, bases: list[str], podman_project: str | None) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="sweepcast-soak-") as tmp:
        tmp_path = Path(tmp)
        if bases:  # a running deployment
            project = podman_project
            started = dt.datetime.now(dt.timezone.utc)
            log = soak(bases, (lambda: podman_roots(project)) if project else dict, minutes, tmp_path)
            errors = podman_log_errors(project, started) if project else []
            target = f"the compose stack {project or ''} at {', '.join(bases)}"
        else:
            log_file = tmp_path / "server.log"
            with serve_app({"SWEEPCAST_DATA_DIR": str(tmp_path / "data")}, log=log_file,
                           args=("--log-level", "warning")) as app:
                log = soak([app.base], lambda: {app.proc.pid: ""}, minutes, tmp_path)
            errors = error_lines(log_file.read_text(errors="replace"))
            target = "the embedded default (`sweepcast serve`: local Ray, SQLite, a fresh data folder)"
    return {"target": target, "minutes": minutes, "answers": log.answers, "jobs": log.jobs, "samples": log.samples,
            "server_log_error_lines": errors[:50], "server_log_error_count": len(errors)}


# --- the figures ----------------------------------------------------------------------------------
def p99(values: list[float]) -> float | None:
    return float(np.percentile(values, 99)) if values else None


def p99_ratio_lower_bound(first: list[float], later: list[float], draws: int = 2000, seed: int = 0) -> float:
    """The one-sided 95 % lower bound of p99(later) / p99(first), by resampling both windows (bootstrap): above
    1.2 means the later window's p99 is more than 20 % over the first's beyond what the windows' few slowest
    answers leave to chance (over 20 answers a p99 is their slowest one, and one slow answer doubles it)."""
    rng = np.random.default_rng(seed)
    a, b = np.asarray(first), np.asarray(later)
    ratios = (np.percentile(rng.choice(b, (draws, b.size)), 99, axis=1)
              / np.percentile(rng.choice(a, (draws, a.size)), 99, axis=1))
    return float(np.percentile(ratios, 5))


def route_windows(answers: list, seconds: float) -> dict[str, list[dict[str, Any]]]:
    """Per route, per ``WINDOW_S`` window: count, p50 and p99 seconds of its answered requests, and (after the
    first window) the lower bound of its p99's ratio to the first window's (:func:`p99_ratio_lower_bound`)."""
    out: dict[str, list[dict[str, Any]]] = {}
    for route in sorted({a[1] for a in answers}):
        rows, first = [], None
        for start in np.arange(0.0, seconds, WINDOW_S):
            got = [a[3] for a in answers if a[1] == route and start <= a[0] < start + WINDOW_S
                   and isinstance(a[2], int) and a[2] < 500]
            first = got if first is None else first
            bound = p99_ratio_lower_bound(first, got) if start > 0 and got and first else None
            rows.append({"from_min": start / 60, "count": len(got), "p50_s": float(np.median(got)) if got else None,
                         "p99_s": p99(got), "p99_ratio_lower_bound": bound})
        out[route] = rows
    return out


def own_mb(sample: dict[str, Any]) -> float:
    """A process's resident memory less the shared memory in it (``RssShmem``): PostgreSQL's backends count each
    page of the shared buffer pool they have read, so their resident memory grows with the pages they touch while
    their own stays put."""
    return sample["rss_mb"] - sample.get("shared_mb", 0.0)


def process_growth(samples: list[dict[str, Any]], warmup_s: float) -> list[dict[str, Any]]:
    """Each process alive from the end of the warm-up to the end: its mean memory, threads and files over the
    5 minutes after the warm-up and over the last 5 minutes, and their growth."""
    end = samples[-1]["t"]
    early = [s for s in samples if warmup_s <= s["t"] < warmup_s + 300]
    late = [s for s in samples if s["t"] >= end - 300]

    def series(group: list[dict], pid: int, key: str) -> list[float]:
        return [own_mb(p) if key == "own_mb" else p[key] for s in group for p in s["processes"] if p["pid"] == pid]

    rows = []
    pids = {p["pid"]: p["title"] for s in early for p in s["processes"]}
    prefixes = {p["pid"]: p.get("prefix", "") for s in early for p in s["processes"]}
    for pid, title in pids.items():
        if not series(late, pid, "rss_mb"):
            continue
        row = {"pid": pid, "role": role(title, prefixes.get(pid, ""))}
        for key in ("rss_mb", "own_mb", "threads", "files"):
            a, b = statistics.mean(series(early, pid, key)), statistics.mean(series(late, pid, key))
            row[f"{key}_after_warmup"], row[f"{key}_end"] = a, b
            row[f"{key}_growth_pct"] = 100.0 * (b - a) / a if a else 0.0
        rows.append(row)
    return sorted(rows, key=lambda r: -r["rss_mb_end"])


def trend(answers: list, after_s: float) -> dict[str, float] | None:
    """How a route's answer times move over the run after ``after_s`` (the warm-up), for routes too sparse for a
    p99 per window (a few answers per 10 minutes): ``rising_p``, the one-sided p-value of Kendall's tau of answer
    time against the time asked (small: they get slower), and ``growth_pct``, the Theil-Sen line's rise from the
    first of those answers to the last, in % of their median."""
    got = [(a[0], a[3]) for a in answers if a[0] >= after_s and isinstance(a[2], int) and a[2] < 500]
    if len(got) < 10:
        return None
    asked, took = (np.asarray(v) for v in zip(*got))
    rise = scipy.stats.theilslopes(took, asked).slope * (asked[-1] - asked[0])
    return {"rising_p": float(scipy.stats.kendalltau(asked, took, alternative="greater").pvalue),
            "growth_pct": float(100.0 * rise / np.median(took))}


DENSE_WINDOW = 100
"""Answers a window needs for its p99 to be told apart from its slowest answer."""


def p99_grew(dense: bool, route: dict[str, Any]) -> bool | None:
    """Whether a route's latency grew by more than 20 % over the run. ``dense`` (every window holds ``DENSE_WINDOW``
    answers): a later window's p99 over the first's has its lower bound above 1.2. Else (too few for a p99): its
    answers get slower after the warm-up beyond chance (``rising_p`` < 0.05) and by more than 20 %."""
    if dense:
        return route["p99_ratio_lower_bound"] is not None and route["p99_ratio_lower_bound"] > 1.2
    sparse = route["trend"]
    return None if sparse is None else sparse["rising_p"] < 0.05 and sparse["growth_pct"] > 20.0


def summarise(raw: dict[str, Any], warmup_s: float) -> dict[str, Any]:
    seconds = 60.0 * raw["minutes"]
    answers = raw["answers"]
    by_route: dict[str, dict[str, Any]] = {}
    for route in sorted({a[1] for a in answers}):
        got = [a for a in answers if a[1] == route]
        by_route[route] = {"requests": len(got),
                           "server_errors": sum(isinstance(a[2], int) and a[2] >= 500 for a in got),
                           "client_errors": sum(isinstance(a[2], int) and 400 <= a[2] < 500 for a in got),
                           "connection_failures": sum(not isinstance(a[2], int) for a in got)}
    windows = route_windows(answers, seconds)
    for route, rows in windows.items():
        first = rows[0]["p99_s"]
        later = [r["p99_s"] for r in rows[1:] if r["p99_s"] is not None]
        by_route[route]["p99_first_window_s"] = first
        by_route[route]["p99_worst_later_window_s"] = max(later) if later else None
        by_route[route]["p99_worst_ratio"] = max(later) / first if later and first else None
        bounds = [r["p99_ratio_lower_bound"] for r in rows[1:] if r["p99_ratio_lower_bound"] is not None]
        by_route[route]["p99_ratio_lower_bound"] = max(bounds) if bounds else None
        dense = all(w["count"] >= DENSE_WINDOW for w in rows)
        by_route[route]["trend"] = None if dense else trend([a for a in answers if a[1] == route], warmup_s)
        by_route[route]["grew"] = p99_grew(dense, by_route[route])
    jobs = raw["jobs"].values()
    kinds = sorted({j["kind"] for j in jobs})
    job_rows = {k: {"accepted": sum(j["kind"] == k for j in jobs),
                    **{state: sum(j["kind"] == k and j["state"] == state for j in jobs) for state in FINAL},
                    "not_ended": sum(j["kind"] == k and j["state"] not in FINAL for j in jobs),
                    "median_s": statistics.median([j["seconds"] for j in jobs if j["kind"] == k and "seconds" in j]
                                                  or [float("nan")])}
                for k in kinds}
    growth = process_growth(raw["samples"], warmup_s)
    totals = {key: [sum(p[key] for p in s["processes"]) for s in raw["samples"]]
              for key in ("rss_mb", "threads", "files")}
    totals["own_mb"] = [sum(map(own_mb, s["processes"])) for s in raw["samples"]]
    times = [s["t"] for s in raw["samples"]]
    total_growth = {}
    for key, values in totals.items():
        early = [v for t, v in zip(times, values) if warmup_s <= t < warmup_s + 300]
        late = [v for t, v in zip(times, values) if t >= times[-1] - 300]
        a, b = statistics.mean(early), statistics.mean(late)
        total_growth[key] = {"after_warmup": a, "end": b, "growth_pct": 100.0 * (b - a) / a}
    return {"routes": by_route, "windows": windows, "jobs": job_rows, "processes": growth, "totals": totals,
            "total_growth": total_growth, "loads": [s["load"] for s in raw["samples"]], "warmup_s": warmup_s,
            "processes_seen": len({p["pid"] for s in raw["samples"] for p in s["processes"]})}


def plots(raw: dict[str, Any], summary: dict[str, Any], name: str) -> list[Path]:
    from benchmarks import _plots

    t = [s["t"] / 60 for s in raw["samples"]]
    colours = ["C0", "C1", "C2", "C3", "C4", "C5", "C6", "C7", "C8", "C9"]
    big = summary["processes"][:8]
    fig, axes = _plots.panels(3, 3, (5.0, 3.4))
    series = {}
    for k, row in enumerate(big):
        ys = [next((p["rss_mb"] for p in s["processes"] if p["pid"] == row["pid"]), np.nan) for s in raw["samples"]]
        series[f"{row['role']} ({row['pid']})"] = (t, ys, colours[k % 10])
    _plots.line_chart(axes[0], "resident memory, largest processes", series, "minute", "MB",
                      vline=summary["warmup_s"] / 60)
    _plots.line_chart(axes[1], "all the service's processes", {"memory (MB)": (t, summary["totals"]["rss_mb"], "C0")},
                      "minute", "MB", vline=summary["warmup_s"] / 60)
    _plots.line_chart(axes[2], "threads and open files, all processes",
                      {"threads": (t, summary["totals"]["threads"], "C1"),
                       "open files": (t, summary["totals"]["files"], "C2")}, "minute", "count",
                      vline=summary["warmup_s"] / 60)
    memory = RESULTS_DIR / f"{name}_memory.png"
    _plots.save(fig, memory)

    routes = sorted(summary["windows"])
    fig, axes = _plots.panels(len(routes), 3, (5.0, 3.2))
    for ax, route in zip(axes, routes):
        got = [a for a in raw["answers"] if a[1] == route and isinstance(a[2], int) and a[2] < 500]
        minutes = sorted({int(a[0] // 60) for a in got})
        p50 = [float(np.median([a[3] for a in got if int(a[0] // 60) == m])) for m in minutes]
        top = [p99([a[3] for a in got if int(a[0] // 60) == m]) for m in minutes]
        _plots.line_chart(ax, route, {"p50": (minutes, p50, "C0"), "p99": (minutes, top, "C3")}, "minute",
                          "seconds")
    latency = RESULTS_DIR / f"{name}_latency.png"
    _plots.save(fig, latency)
    return [memory, latency]


def _f(value: float | None, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _totals(growth: dict[str, dict[str, float]]) -> list[str]:
    m, t, f = growth["rss_mb"], growth["threads"], growth["files"]
    return [_f(m["after_warmup"], 0), _f(m["end"], 0), _f(m["growth_pct"], 1), _f(growth["own_mb"]["growth_pct"], 1),
            f"{t['after_warmup']:.0f} -> {t['end']:.0f}", _f(t["growth_pct"], 1),
            f"{f['after_warmup']:.0f} -> {f['end']:.0f}", _f(f["growth_pct"], 1)]


def markdown(summary: dict[str, Any], raw: dict[str, Any], pictures: list[Path]) -> str:
    loads = summary["loads"]
    md = [f"{raw['target'][0].upper()}{raw['target'][1:]} for {raw['minutes']:g} minutes under the load generator of `benchmarks/soak.py` (photo batches of "
          f"{BATCH_PHOTOS} every {BATCH_EVERY_S:g} s, {VIEWERS} viewers orbiting at {VIEWER_FPS:g} fps at "
          f"{VIEW_SIZE[0]}x{VIEW_SIZE[1]} / {VIEW_PLANES} planes with a new session every "
          f"{VIEWER_SESSION_S / 60:g} min, a 36-frame reconstruction every {RECONSTRUCT_EVERY_S / 60:g} min, live "
          f"ingest at {LIVE_RATE:g} frame sets/s, `/readyz` every {READY_EVERY_S:g} s). Load average over the run: "
          f"median {statistics.median(loads):.2f}, max {max(loads):.2f} (this machine's 2 cores; the load is the "
          f"soak's own unless the closing note says otherwise). Warm-up: the first {summary['warmup_s'] / 60:g} min.",
          "", "Answers per route (p99 per 10-minute window, of the answers under 500):", "",
          md_table(["route", "requests", "per 10 min", "5xx", "4xx", "connection failures", "p50 first 10 min (s)",
                    "p50 last 10 min (s)", "p99 first 10 min (s)", "worst later p99 (s)", "worst / first",
                    "later / first, 95 % lower bound", "sparse: rising p", "sparse: growth %", "grew > 20 %"],
                   [[route, r["requests"], f"{r['requests'] / len(summary['windows'][route]):.0f}",
                     r["server_errors"], r["client_errors"], r["connection_failures"],
                     _f(summary["windows"][route][0]["p50_s"]), _f(summary["windows"][route][-1]["p50_s"]),
                     _f(r["p99_first_window_s"]), _f(r["p99_worst_later_window_s"]), _f(r["p99_worst_ratio"], 2),
                     _f(r["p99_ratio_lower_bound"], 2), _f((r["trend"] or {}).get("rising_p"), 3),
                     _f((r["trend"] or {}).get("growth_pct"), 1),
                     {True: "**yes**", False: "no", None: "-"}[r["grew"]]]
                    for route, r in summary["routes"].items()]),
          "", "(A p99 over a window of fewer than 100 answers is its slowest one or two. The last column: the largest, "
              "over the later windows, of the one-sided 95 % lower bound of that window's p99 over the first's, by "
              "resampling both windows' answers. For a route with a window of fewer than "
              f"{DENSE_WINDOW} answers, its answers after the warm-up instead: rising p, the one-sided p-value of "
              "Kendall's tau of answer time against the time asked; growth, the Theil-Sen line's rise over them in % "
              f"of their median. Grew: the lower bound above 1.20 where every window holds {DENSE_WINDOW} answers, "
              "else rising p under 0.05 and growth over 20 %.)",
          "", "Jobs (those still running at the end followed to their end):", "",
          md_table(["kind", "accepted", "succeeded", "failed", "cancelled", "never ended", "median s"],
                   [[k, j["accepted"], j["succeeded"], j["failed"], j["cancelled"], j["not_ended"],
                     _f(j["median_s"], 1)] for k, j in summary["jobs"].items()]),
          "", "Processes alive from the end of the warm-up to the end (means over the 5 minutes after the warm-up "
              "and the last 5 minutes):", "",
          md_table(["process", "memory MB after warm-up", "at the end", "growth %", "own memory growth %", "threads",
                    "growth %", "open files", "growth %"],
                   [[f"{p['role']} ({p['pid']})", _f(p["rss_mb_after_warmup"], 0), _f(p["rss_mb_end"], 0),
                     _f(p["rss_mb_growth_pct"], 1), _f(p["own_mb_growth_pct"], 1),
                     f"{p['threads_after_warmup']:.0f} -> {p['threads_end']:.0f}",
                     _f(p["threads_growth_pct"], 1), f"{p['files_after_warmup']:.0f} -> {p['files_end']:.0f}",
                     _f(p["files_growth_pct"], 1)] for p in summary["processes"]]
                   + [[f"all the service's processes ({summary['processes_seen']} seen over the run)",
                       *_totals(summary["total_growth"])]]),
          "", f"Server log lines naming an error: {raw['server_log_error_count']}"
          + ("." if not raw["server_log_error_lines"] else ", the first of them:"), "",
          *[f"    {line[:300]}" for line in raw["server_log_error_lines"][:10]], "",
          "Plots: " + ", ".join(f"`{shown_path(p)}`" for p in pictures) + "."]
    return "\n".join(md)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=60.0, help="how long the load runs (default 60)")
    parser.add_argument("--warmup-minutes", type=float, default=None,
                        help="the warm-up left out of the growth figures (default: 10, or a sixth of a shorter run)")
    parser.add_argument("--name", default="soak_embedded", help="the results name (default soak_embedded)")
    parser.add_argument("--base", action="append", default=[],
                        help="a running service's URL (repeat for each API replica); the key from SWEEPCAST_API_KEYS")
    parser.add_argument("--podman-project", help="the compose project whose containers' processes are sampled")
    parser.add_argument("--raw", help="also write every answer, job and process sample to this JSON file")
    args = parser.parse_args(argv)
    exit_on_sigterm()
    warmup = 60.0 * (args.warmup_minutes if args.warmup_minutes is not None else min(10.0, args.minutes / 6))
    if args.base and os.environ.get("SWEEPCAST_API_KEYS"):
        HEADERS["Authorization"] = f"Bearer {os.environ['SWEEPCAST_API_KEYS'].split(',')[0]}"
    raw = run(args.minutes, args.base, args.podman_project)
    if args.raw:
        Path(args.raw).parent.mkdir(parents=True, exist_ok=True)
        Path(args.raw).write_text(json.dumps(raw))
    summary = summarise(raw, warmup)
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    pictures = plots(raw, summary, args.name)
    publish(args.name, {"summary": summary}, markdown(summary, raw, pictures))
    print(markdown(summary, raw, pictures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
