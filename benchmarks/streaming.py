"""Virtual-view streaming benchmark: concurrent WebSocket viewers against a running server.

Starts ``python -m app serve`` on a free port with a fresh data folder (so the first-run demo rig is
built: 10 cameras, 320x240, the procedural studio), waits for the demo recording, then for 1, 4 and
16 concurrent viewers at 320x240 and 640x480 (48 planes, Kojima weighting, coarse-to-fine sweep,
visual hull from the recording's backgrounds) measures:

- frames per second per viewer (each viewer is closed-loop: it sends its next viewpoint, moving
  around the rig, as soon as the previous frame arrives, so no request waits behind a stale one);
- latency p50 / p95 from sending a viewpoint to receiving its frame (client-side clock);
- the server's CPU use in cores (the server process and all its descendants: Ray, the session actor);
- the session's own render time (from the frame headers).

Baseline in the same run: the same views rendered in this process by ``SweepRenderer`` directly
(median of repeated renders, server idle, just before each size's viewers), so the streaming
overhead is latency minus render time.
Also recorded: the first-run times (server answering, demo recording ready, first frame received).

Run: ``python benchmarks/streaming.py [--quick]`` from the repository root.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np
import websockets

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import md_table, publish  # noqa: E402
from tests.servers import exit_on_sigterm, serve_app  # noqa: E402
from workers.streaming.framing import unpack_message  # noqa: E402
from workers.streaming.params import Viewpoint  # noqa: E402
from workers.streaming.recording import RecordingArchive  # noqa: E402
from workers.streaming.store import archive_key, load_rig  # noqa: E402
from workers.streaming.viewpoint import orbit_frame, virtual_camera  # noqa: E402
from workers.storage import open_store  # noqa: E402
from workers.sweep.renderer import RenderOptions, SweepRenderer  # noqa: E402

VIEWERS = (1, 4, 16)
SIZES = ((320, 240), (640, 480))
PLANES = 48
WARMUP_FRAMES = 3
STEP_DEG = 1.5
TARGET = {"fps": 15.0, "latency_p95_ms": 150.0}


# --- the server's CPU time (the process tree under the server's pid) -------------------------------
def _tree(root: int) -> list[int]:
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
                parents[int(entry.name)] = int(fields[1])
            except (OSError, IndexError, ValueError):
                continue
    tree, frontier = [root], [root]
    while frontier:
        frontier = [pid for pid, parent in parents.items() if parent in frontier]
        tree += frontier
    return tree


def cpu_seconds(root: int) -> float:
    """User + system CPU seconds of ``root`` and its descendants alive now."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0
    for pid in _tree(root):
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            total += int(fields[11]) + int(fields[12])  # utime, stime
        except (OSError, IndexError, ValueError):
            continue
    return total / tick


# --- viewers -------------------------------------------------------------------------------------
def view_message(i: int, phase: float, size: tuple[int, int]) -> dict:
    azimuth = -40.0 + (phase + i * STEP_DEG) % 80.0  # sweep the rig's arc, a new pose every frame
    return {"type": "view", "id": i, "orbit": {"azimuth": azimuth}, "width": size[0], "height": size[1],
            "planes": PLANES, "method": "kojima", "frame": 0, "quality": 80}


async def viewer(url: str, size: tuple[int, int], phase: float, start: asyncio.Event, warm: asyncio.Queue,
                 seconds: float) -> dict:
    """One closed-loop viewer: warm up, wait for the others, then measure for ``seconds``."""
    async with websockets.connect(url, max_size=None) as ws:
        while json.loads(await ws.recv())["type"] != "ready":
            pass
        i = 0

        async def one() -> tuple[float, dict]:
            nonlocal i
            i += 1
            t0 = time.perf_counter()
            await ws.send(json.dumps(view_message(i, phase, size)))
            while True:
                message = await ws.recv()
                if isinstance(message, bytes):
                    header, _ = unpack_message(message)
                    if header["id"] == i:
                        return (time.perf_counter() - t0) * 1e3, header
                elif json.loads(message).get("type") == "error":
                    raise RuntimeError(message)

        for _ in range(WARMUP_FRAMES):
            await one()
        await warm.put(1)
        await start.wait()
        latencies, renders = [], []
        t_end = time.perf_counter() + seconds
        while True:
            latency, header = await one()
            if time.perf_counter() > t_end:  # only frames received within the window count
                return {"latencies": latencies, "renders": renders, "seconds": seconds}
            latencies.append(latency)
            renders.append(header["render_ms"])


async def run_config(url: str, n: int, size: tuple[int, int], seconds: float, server_pid: int) -> dict:
    start, warm = asyncio.Event(), asyncio.Queue()
    tasks = [asyncio.create_task(viewer(url, size, 80.0 * k / n, start, warm, seconds)) for k in range(n)]
    for _ in range(n):
        await warm.get()
    cpu0, t0 = cpu_seconds(server_pid), time.perf_counter()
    start.set()
    results = await asyncio.gather(*tasks)
    wall = time.perf_counter() - t0
    cpu = (cpu_seconds(server_pid) - cpu0) / wall
    latencies = np.concatenate([r["latencies"] for r in results])
    renders = np.concatenate([r["renders"] for r in results])
    if not len(latencies):
        raise SystemExit(f"no frame arrived within {seconds} s with {n} viewers at {size}: give --seconds more")
    fps = [len(r["latencies"]) / r["seconds"] for r in results]
    return {
        "fps": float(np.mean(fps)), "fps_min": float(np.min(fps)), "total_fps": float(np.sum(fps)),
        "latency_p50_ms": float(np.percentile(latencies, 50)), "latency_p95_ms": float(np.percentile(latencies, 95)),
        "render_p50_ms": float(np.percentile(renders, 50)), "server_cpu_cores": float(cpu),
        "frames": int(len(latencies)),
    }


# --- the baseline: the renderer alone ----------------------------------------------------------------
class Baseline:
    """The renderer alone in this process on the demo recording's frame 0 (the server idle)."""

    def __init__(self, data_dir: Path, rig_id: str, recording_id: str) -> None:
        store = open_store((data_dir / "blobs").resolve().as_uri())
        rig = load_rig(store, rig_id)
        archive = RecordingArchive(store.local_path(archive_key(recording_id)))
        self.renderer = SweepRenderer(rig, archive.frame_set(0), backgrounds=archive.backgrounds())
        self.frame = orbit_frame(rig)

    def measure(self, size: tuple[int, int], repeats: int) -> dict:
        times = []
        for i in range(repeats + WARMUP_FRAMES):
            vp = Viewpoint.model_validate(view_message(i, 0.0, size))
            cam = virtual_camera(vp, self.frame, size)
            t0 = time.perf_counter()
            self.renderer.render(cam, RenderOptions(**vp.render_fields()))
            if i >= WARMUP_FRAMES:
                times.append((time.perf_counter() - t0) * 1e3)
        return {"render_p50_ms": statistics.median(times), "render_p95_ms": float(np.percentile(times, 95))}


# --- the server ----------------------------------------------------------------------------------
def wait_for(check, timeout: float, what: str, proc: subprocess.Popen, log: Path):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise SystemExit(f"the server exited while waiting for {what}; its log:\n{log.read_text()[-3000:]}")
        try:
            value = check()
            if value:
                return value
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    raise SystemExit(f"timed out waiting for {what}")


def demo_recording(http: httpx.Client) -> tuple[str, dict] | None:
    rigs = [r for r in http.get("/v1/rigs").json()["rigs"] if r["demo"]]
    if not rigs:
        return None
    recordings = http.get(f"/v1/rigs/{rigs[0]['id']}").json()["recordings"]
    if recordings and recordings[0]["state"] == "failed":
        raise SystemExit(f"the demo recording failed: {recordings[0]['error']}")
    if recordings and recordings[0]["state"] == "ready":
        return rigs[0]["id"], recordings[0]
    return None


async def first_frame(url: str) -> None:
    async with websockets.connect(url, max_size=None) as ws:
        await ws.send(json.dumps(view_message(1, 0.0, (320, 240))))
        while not isinstance(await ws.recv(), bytes):
            pass


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="5 s per configuration instead of 15")
    ap.add_argument("--seconds", type=float, help="measurement time per configuration")
    args = ap.parse_args()
    seconds = args.seconds or (5.0 if args.quick else 15.0)
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="sweepcast-bench-") as tmp:
        data_dir = Path(tmp) / "data"
        log = Path(tmp) / "server.log"
        t_start = time.monotonic()
        with serve_app({"SWEEPCAST_DATA_DIR": str(data_dir)}, log=log, wait=False) as app:
            proc = app.proc
            app.wait_ready(120)
            ready_s = time.monotonic() - t_start
            with httpx.Client(base_url=app.base, timeout=30) as http:
                rig_id, recording = wait_for(lambda: demo_recording(http), 900, "the demo recording", proc, log)
                demo_s = time.monotonic() - t_start
            url = f"{app.base.replace('http', 'ws')}/v1/rigs/{rig_id}/view?source={recording['id']}"
            asyncio.run(first_frame(url))
            first_frame_s = time.monotonic() - t_start
            print(f"server ready {ready_s:.1f} s, demo recording {demo_s:.1f} s, first frame {first_frame_s:.1f} s "
                  f"after start", file=sys.stderr)
            results: dict = {"viewers": {}, "baseline": {}}
            base = Baseline(data_dir, rig_id, recording["id"])
            for size in SIZES:
                key = f"{size[0]}x{size[1]}"
                results["baseline"][key] = base.measure(size, 5 if args.quick else 15)  # just before its viewers
                for n in VIEWERS:
                    r = asyncio.run(run_config(url, n, size, seconds, proc.pid))
                    results["viewers"].setdefault(str(n), {})[key] = r
                    print(f"{n:2d} viewers {key}: {r['fps']:.1f} fps each, latency p50 {r['latency_p50_ms']:.0f} ms "
                          f"p95 {r['latency_p95_ms']:.0f} ms, server {r['server_cpu_cores']:.2f} cores",
                          file=sys.stderr)
    one = results["viewers"]["1"]["320x240"]
    results["first_run"] = {"server_ready_s": ready_s, "demo_ready_s": demo_s, "first_frame_s": first_frame_s}
    results["target"] = {**TARGET, "met": one["fps"] >= TARGET["fps"] and one["latency_p95_ms"] <= TARGET["latency_p95_ms"]}
    results["setup"] = {"cameras": 10, "camera_size": "320x240", "planes": PLANES, "method": "kojima",
                        "coarse_to_fine": True, "visual_hull": True, "seconds_per_config": seconds,
                        "load_average_before": load_before}
    publish("streaming", results, markdown(results))
    return 0


def markdown(results: dict) -> str:
    rows = []
    for n, sizes in results["viewers"].items():
        for size, r in sizes.items():
            rows.append([n, size, r["fps"], r["total_fps"], r["latency_p50_ms"], r["latency_p95_ms"],
                         r["render_p50_ms"], results["baseline"][size]["render_p50_ms"], r["server_cpu_cores"]])
    fr = results["first_run"]
    t = results["target"]
    return (
        "Concurrent WebSocket viewers of the demo rig (10 cameras at 320x240, 48 planes, Kojima weighting, "
        "coarse-to-fine sweep, visual hull). Each viewer sends its next viewpoint when the previous frame "
        "arrives; latency is viewpoint sent -> frame received. Baseline: the renderer alone in the benchmark "
        f"process, same views. Load average before the run: {results['setup']['load_average_before']:.2f}"
        + (" (above ~0.5 on this 2-core machine: other work shared the CPU and the speeds are low)"
           if results["setup"]["load_average_before"] > 0.5 else "") + ".\n\n"
        + md_table(["viewers", "size", "fps per viewer", "fps total", "latency p50 ms", "latency p95 ms",
                    "session render p50 ms", "baseline render p50 ms", "server CPU cores"], rows)
        + f"\n\nTarget (1 viewer, 320x240): >= {t['fps']:g} fps with p95 <= {t['latency_p95_ms']:g} ms: "
        f"{'met' if t['met'] else 'not met'}.\n\n"
        f"First run from a fresh data folder: server answering after {fr['server_ready_s']:.1f} s, demo recording "
        f"ready after {fr['demo_ready_s']:.1f} s, first frame after {fr['first_frame_s']:.1f} s.\n"
    )


if __name__ == "__main__":
    with exit_on_sigterm():  # SIGTERM unwinds the serve_app block, which stops the server and its Ray
        raise SystemExit(main())
