"""Virtual-view streaming benchmark: concurrent WebSocket viewers against a running server.

Starts ``python -m app serve`` on a free port with a fresh data folder (so the first-run demo rig is
built: 10 cameras, 640x480, the photographic studio), waits for the demo recording, then for 1, 4 and
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
Also recorded: the first-run times (server ready, demo recording ready, first frame received).

Run: ``python -m benchmarks.streaming --only viewers [--quick]`` from the repository root (this part, results
``streaming``; with ``--viewers``, ``--sizes`` or ``--planes`` other than the defaults a steady-state run of its own,
``streaming_viewers[_pN]``). Without ``--only`` every part below runs too, each writing its own results.

Client mode (the virtual view rendered in the viewer's browser, WebGL2, headless Chromium):
``python -m benchmarks.streaming_browser --only quality|fps|cost|latency|first_frame [...]``
(:mod:`benchmarks.streaming_browser`).

Three more parts, each its own results section:

- ``viewer_sizes [--quiet 1.5]``: one viewer of the demo rig at each of CANDIDATE_SIZES (4:3, 320x240 ..
  960x720): fps, latency p50/p95; the largest size with >= 20 fps is the viewer's default (``app.settings.
  DEFAULT_VIEWER_SIZE``, set by hand from this table). ``--quiet L`` waits before each size (up to 3 min)
  for the 1-minute load average to fall under L (the machine is shared). Section ``streaming_viewer_size``.
- ``hd [--hd-frames 6]``: real-rig sizes. (1) Undistortion at ``set_frames``: a 10-camera 1920x1080 rig with strong
  barrel distortion, ms per frame set for the remaps alone and for set_frames with and without
  distortion. (2) An 8-camera 1920x1080 distorted recording of the studio (rendered through the lens,
  H.264 videos + empty-studio PNGs) imported through the API (seconds until ready). (3) One viewer at
  640x360 on it, closed loop: orbiting on one frame, and playing (a new frame with every view), fps and
  latency p50/p95, and the session's cost per new frame set (decode, shrink 3x, set_frames). Section
  ``streaming_hd``.
- ``live [--viewers-live 1]``: live camera streams (the paper's use). A rig of 10 cameras 640x480 (the demo
  rig's) is created through the API; frame sets of the studio with its moving ball (rendered here, JPEG quality
  90, ~50 KB per camera) are pushed over ``/v1/rigs/{id}/live`` closed-loop (the next set as soon as the previous
  one is acknowledged) while viewers on ``?source=live`` render 320x240 views closed-loop. Reports ingest sets/s,
  ack latency p50/p95 (set sent -> ack), the session's decode/apply/lock-wait time per set, and each viewer's
  fps and latency meanwhile; anchors in the same run: the viewer alone (no ingest) and the ingest alone (no
  viewer). Section ``streaming_live``.
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
from typing import Any

import cv2
import httpx
import numpy as np
import websockets

from harness.proc import tree_cpu_seconds
from benchmarks._report import Sections, md_table
from benchmarks._timing import load_note, wait_quiet
from harness.servers import CHECKOUT_KERNEL_CACHE, exit_on_sigterm, serve_app
from workers.streaming.framing import unpack_message
from workers.streaming.params import Viewpoint
from workers.streaming.recording import RecordingArchive
from workers.streaming.store import archive_key, load_rig
from workers.streaming.viewpoint import orbit_frame, virtual_camera
from workers.storage import open_store
from workers.sweep.renderer import RenderOptions, SweepRenderer
from workers.camera import Camera
from workers.sweep.rig import Rig

VIEWERS = (1, 4, 16)
SIZES = ((320, 240), (640, 480))
PLANES = 48
WARMUP_FRAMES = 3
STEP_DEG = 1.5
TARGET = {"fps": 15.0, "latency_p95_ms": 150.0}


# --- viewers -------------------------------------------------------------------------------------
def view_message(i: int, phase: float, size: tuple[int, int], frames: int = 1, planes: int = PLANES) -> dict:
    """Viewpoint ``i``: a new pose on the rig's arc every time; frame 0, or frame i mod ``frames``."""
    azimuth = -40.0 + (phase + i * STEP_DEG) % 80.0  # sweep the rig's arc, a new pose every frame
    return {"type": "view", "id": i, "orbit": {"azimuth": azimuth}, "width": size[0], "height": size[1],
            "planes": planes, "method": "kojima", "frame": i % frames, "quality": 80}


async def viewer(url: str, size: tuple[int, int], phase: float, start: asyncio.Event, warm: asyncio.Queue,
                 seconds: float, frames: int = 1, planes: int = PLANES) -> dict:
    """One closed-loop viewer: warm up, wait for the others, then measure for ``seconds``."""
    async with websockets.connect(url, max_size=None) as ws:
        while json.loads(await ws.recv())["type"] != "ready":
            pass
        i = 0

        async def one() -> tuple[float, dict]:
            nonlocal i
            i += 1
            t0 = time.perf_counter()
            await ws.send(json.dumps(view_message(i, phase, size, frames, planes)))
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


async def run_config(url: str, n: int, size: tuple[int, int], seconds: float, server_pid: int,
                     frames: int = 1, planes: int = PLANES) -> dict:
    start, warm = asyncio.Event(), asyncio.Queue()
    tasks = [asyncio.create_task(viewer(url, size, 80.0 * k / n, start, warm, seconds, frames, planes))
             for k in range(n)]
    for _ in range(n):
        await warm.get()
    cpu0, t0 = tree_cpu_seconds(server_pid), time.perf_counter()
    start.set()
    results = await asyncio.gather(*tasks)
    wall = time.perf_counter() - t0
    cpu = (tree_cpu_seconds(server_pid) - cpu0) / wall
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

    def measure(self, size: tuple[int, int], repeats: int, planes: int = PLANES) -> dict:
        times = []
        for i in range(repeats + WARMUP_FRAMES):
            vp = Viewpoint.model_validate(view_message(i, 0.0, size, planes=planes))
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


async def frame_reply(ws: Any, view_id: int | None = None) -> bytes:
    """The next frame a view socket sends (of viewpoint ``view_id`` when given), skipping its text messages;
    RuntimeError with the server's message when it answers an error instead."""
    while True:
        message = await ws.recv()
        if isinstance(message, bytes):
            if view_id is None or unpack_message(message)[0]["id"] == view_id:
                return message
        elif json.loads(message).get("type") == "error":
            raise RuntimeError(f"the viewer got an error: {message}")


async def first_frame(url: str) -> None:
    """Open a view socket on ``url``, ask for one 320x240 view and wait for its frame."""
    async with websockets.connect(url, max_size=None) as ws:
        await ws.send(json.dumps(view_message(1, 0.0, (320, 240))))
        await frame_reply(ws)


def default_grid(args: argparse.Namespace) -> bool:
    """Whether the viewers part runs its default grid (the viewer counts, sizes and planes of ``streaming``)."""
    return (args.viewers == list(VIEWERS) and args.sizes == [f"{w}x{h}" for w, h in SIZES] and args.planes == PLANES)


def viewers_results(args: argparse.Namespace) -> str:
    """The viewers part's results: ``streaming`` for the default grid, else ``streaming_viewers[_pN]`` (a steady-state
    run of its own)."""
    if default_grid(args):
        return "streaming"
    return "streaming_viewers" + (f"_p{args.planes}" if args.planes != PLANES else "")


def bench_viewers(args: argparse.Namespace) -> tuple[dict, str]:
    """The part ``viewers`` (the module docstring): concurrent viewers of the first-run demo at each size."""
    seconds = seconds_per_config(args)
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="sweepcast-bench-") as tmp:
        data_dir = Path(tmp) / "data"
        log = Path(tmp) / "server.log"
        t_start = time.monotonic()
        env = {"SWEEPCAST_DATA_DIR": str(data_dir)}
        if not default_grid(args):  # steady state only (its own section): kernels from the checkout's cache, not compiled first
            env["SWEEPCAST_NUMBA_CACHE_DIR"] = str(CHECKOUT_KERNEL_CACHE)
        with serve_app(env, log=log, wait=False) as app:
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
            for size in [tuple(int(v) for v in k.split("x")) for k in args.sizes]:
                key = f"{size[0]}x{size[1]}"
                results["baseline"][key] = base.measure(size, 5 if args.quick else 15, args.planes)  # before its viewers
                for n in args.viewers:
                    r = asyncio.run(run_config(url, n, size, seconds, proc.pid, planes=args.planes))
                    results["viewers"].setdefault(str(n), {})[key] = r
                    print(f"{n:2d} viewers {key}: {r['fps']:.1f} fps each, latency p50 {r['latency_p50_ms']:.0f} ms "
                          f"p95 {r['latency_p95_ms']:.0f} ms, server {r['server_cpu_cores']:.2f} cores",
                          file=sys.stderr)
    results["first_run"] = {"server_ready_s": ready_s, "demo_ready_s": demo_s, "first_frame_s": first_frame_s}
    one = results["viewers"].get("1", {}).get("320x240")  # the target's configuration, when this run had it
    results["target"] = {**TARGET, "met": None if one is None else
                         one["fps"] >= TARGET["fps"] and one["latency_p95_ms"] <= TARGET["latency_p95_ms"]}
    results["setup"] = {"cameras": 10, "camera_size": "640x480", "planes": args.planes, "method": "kojima",
                        "coarse_to_fine": True, "visual_hull": True, "seconds_per_config": seconds,
                        "load_average_before": load_before}
    return results, markdown(results)


ISSUE_GOALS = {("1", "640x480", 64): (30.0, 40.0), ("8", "320x240", 48): (15.0, None)}
"""Issue 21's viewer goals: (viewers, size, planes) -> (fps per viewer, latency p95 ms or None)."""
CORES = os.cpu_count() or 1


def cpu_ms_per_frame(r: dict) -> float:
    """The server's CPU (every process of it: API, Ray, session actor) per frame delivered, ms."""
    return r["server_cpu_cores"] * 1e3 / r["total_fps"]


def goal_lines(results: dict) -> list[str]:
    """The issue's goals this run measured: met or not, and where not, the CPU it would take."""
    lines = []
    planes = results["setup"]["planes"]
    for (n, size, goal_planes), (fps, p95) in ISSUE_GOALS.items():
        r = results["viewers"].get(n, {}).get(size)
        if r is None or planes != goal_planes:
            continue
        met = r["fps"] >= fps and (p95 is None or r["latency_p95_ms"] <= p95)
        ms = cpu_ms_per_frame(r)
        need = int(n) * fps * ms / 1e3
        line = (f"- {n} viewer(s) at {size}, {planes} planes: goal >= {fps:g} fps each"
                + (f" and p95 <= {p95:g} ms" if p95 else "") + f"; measured {r['fps']:.1f} fps, p95 "
                f"{r['latency_p95_ms']:.0f} ms: **{'met' if met else 'not met'}**.")
        if not met:
            line += (f" Limit: CPU. The server spends {ms:.0f} ms of CPU per frame (all its processes), so "
                     f"{int(n) * fps:g} frames/s need {need:.1f} cores; this machine has {CORES}, and one view's "
                     f"render alone takes {r['render_p50_ms']:.0f} ms on its threads (`sweep_gpu` in this file: the "
                     "GPU path renders such a view in a fraction of that).")
        lines.append(line)
    return lines


def markdown(results: dict) -> str:
    rows = []
    for n, sizes in results["viewers"].items():
        for size, r in sizes.items():
            rows.append([n, size, r["fps"], r["total_fps"], r["latency_p50_ms"], r["latency_p95_ms"],
                         r["render_p50_ms"], results["baseline"][size]["render_p50_ms"], r["server_cpu_cores"],
                         round(cpu_ms_per_frame(r), 1)])
    fr = results["first_run"]
    t = results["target"]
    return (
        f"Concurrent WebSocket viewers of the demo rig (10 cameras at 640x480, {results['setup']['planes']} planes, "
        "Kojima weighting, coarse-to-fine sweep, visual hull). Each viewer sends its next viewpoint when the "
        "previous frame arrives; latency is viewpoint sent -> frame received. Baseline: the renderer alone in the benchmark "
        "process, same views. " + load_note(results["setup"]["load_average_before"]) + "\n\n"
        + md_table(["viewers", "size", "fps per viewer", "fps total", "latency p50 ms", "latency p95 ms",
                    "session render p50 ms", "baseline render p50 ms", "server CPU cores", "server CPU ms per frame"],
                   rows)
        + "\n\n" + (f"Target (1 viewer, 320x240): >= {t['fps']:g} fps with p95 <= {t['latency_p95_ms']:g} ms: "
                    f"{'met' if t['met'] else 'not met'}.\n\n" if t["met"] is not None else "")
        + "".join(line + "\n" for line in goal_lines(results)) + ("\n" if goal_lines(results) else "")
        + f"First run from a fresh data folder: server ready (`/readyz`) after {fr['server_ready_s']:.1f} s, demo recording "
        f"ready after {fr['demo_ready_s']:.1f} s, first frame after {fr['first_frame_s']:.1f} s.\n"
    )


# --- the viewer's default size -----------------------------------------------------------------------
CANDIDATE_SIZES = ((320, 240), (400, 300), (480, 360), (560, 420), (640, 480), (800, 600), (960, 720))
DEFAULT_SIZE_FPS = 20.0


def viewer_sizes(args: argparse.Namespace) -> tuple[dict, str]:
    """The part ``viewer_sizes``: one closed-loop viewer of the first-run demo at each candidate size; the table and
    the largest size with >= DEFAULT_SIZE_FPS. With ``--quiet``, each size waits (up to 3 minutes) for the load
    average to fall under it."""
    seconds, quiet = seconds_per_config(args), args.quiet
    load_before = os.getloadavg()[0]
    rows = {}
    with tempfile.TemporaryDirectory(prefix="sweepcast-bench-") as tmp:
        data_dir, log = Path(tmp) / "data", Path(tmp) / "server.log"
        t_start = time.monotonic()
        with serve_app({"SWEEPCAST_DATA_DIR": str(data_dir)}, log=log, wait=False) as app:
            app.wait_ready(120)
            with httpx.Client(base_url=app.base, timeout=30) as http:
                rig_id, recording = wait_for(lambda: demo_recording(http), 900, "the demo recording", app.proc, log)
            demo_s = time.monotonic() - t_start
            url = f"{app.base.replace('http', 'ws')}/v1/rigs/{rig_id}/view?source={recording['id']}"
            asyncio.run(first_frame(url))
            for size in CANDIDATE_SIZES:
                load = wait_quiet(quiet, 180.0) if quiet else os.getloadavg()[0]
                r = asyncio.run(run_config(url, 1, size, seconds, app.proc.pid))
                rows[f"{size[0]}x{size[1]}"] = {**r, "load_average": load}
                print(f"{size[0]}x{size[1]}: {r['fps']:.1f} fps, p95 {r['latency_p95_ms']:.0f} ms", file=sys.stderr)
    passing = [k for k, r in rows.items() if r["fps"] >= DEFAULT_SIZE_FPS]
    chosen = passing[-1] if passing else None
    results = {"sizes": rows, "chosen": chosen, "threshold_fps": DEFAULT_SIZE_FPS, "demo_ready_s": demo_s,
               "setup": {"viewers": 1, "planes": PLANES, "method": "kojima", "coarse_to_fine": True,
                         "visual_hull": True, "seconds_per_config": seconds, "load_average_before": load_before}}
    return results, viewer_size_markdown(results)


def viewer_size_markdown(results: dict) -> str:
    """The streaming_viewer_size section of RESULTS.md from its results."""
    rows = results["sizes"]
    table = md_table(["size", "fps", "latency p50 ms", "latency p95 ms", "session render p50 ms", "server CPU cores",
                      "load avg at start"],
                     [[k, r["fps"], r["latency_p50_ms"], r["latency_p95_ms"], r["render_p50_ms"], r["server_cpu_cores"],
                       r["load_average"]] for k, r in rows.items()])
    return (
        "One closed-loop WebSocket viewer of the first-run demo (10 cameras 640x480, the photographic studio; 48 "
        "planes, Kojima, coarse-to-fine, 5x5 window, visual hull) per view size. "
        f"Load average before the run: {results['setup']['load_average_before']:.2f}; the demo recording was ready "
        f"{results['demo_ready_s']:.0f} s after the server started.\n\n{table}\n\n"
        f"Largest size with >= {results['threshold_fps']:g} fps: **{results['chosen'] or 'none'}** (the viewer's "
        "default: `app.settings.DEFAULT_VIEWER_SIZE`, `SWEEPCAST_VIEWER_SIZE`).\n")


# --- real-rig sizes: undistortion, an HD recording, a 640x360 viewer -----------------------------------
HD_SIZE = (1920, 1080)
HD_DIST = (-0.28, 0.09, 0.0005, -0.0004, -0.012)
HD_VIEW = (640, 360)


def hd_rig(n: int) -> Rig:
    """``n`` 1920x1080 cameras (60 deg horizontal field) on a 90-degree arc round the studio, with
    strong barrel distortion HD_DIST (a wide studio lens)."""
    from workers.synth import default_arc_rig

    return Rig(tuple(default_arc_rig(n, arc_deg=90.0, width=HD_SIZE[0], height=HD_SIZE[1], fov_deg=60.0,
                                     dist=HD_DIST)))


def median_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return float(statistics.median(times))


def undistortion_cost(images: list[np.ndarray], repeats: int = 7) -> dict:
    """ms per 10-camera 1920x1080 frame set: the renderer's remaps alone, set_frames with distortion,
    set_frames of the same rig without distortion (no backgrounds: no silhouettes)."""
    rig = hd_rig(10)
    frames = [images[i % len(images)] for i in range(10)]
    distorted = SweepRenderer(rig, frames)
    pinhole = SweepRenderer(Rig(tuple(Camera(c.name, c.K, c.R, c.t, c.width, c.height) for c in rig.cameras)),
                            frames)
    remap = median_ms(lambda: [distorted.undistort(i, f) for i, f in enumerate(frames)], repeats)
    with_dist = median_ms(lambda: distorted.set_frames(frames), repeats)
    without = median_ms(lambda: pinhole.set_frames(frames), repeats)
    return {"cameras": 10, "size": f"{HD_SIZE[0]}x{HD_SIZE[1]}", "remap_ms": remap, "set_frames_ms": with_dist,
            "set_frames_pinhole_ms": without, "undistortion_ms": with_dist - without}


def hd(args: argparse.Namespace) -> tuple[dict, str]:
    """The part ``hd`` (the module docstring): undistortion, an HD recording imported, a 640x360 viewer on it."""
    import dataclasses

    from workers.streaming.demo import demo_scene
    from workers.streaming.recording import RecordingArchive as Archive
    from workers.streaming.session import shrunk_images, shrunk_rig, source_factor
    from workers.streaming.video import H264Writer
    from workers.synth import Sphere, render_moved, render_views
    from workers.sweep.rig_io import rig_to_dict

    def ball(scene):
        return next(o for o in scene.objects if isinstance(o, Sphere) and o.radius < 0.2)

    seconds, frames = seconds_per_config(args), args.hd_frames
    load_before = os.getloadavg()[0]
    rig = hd_rig(8)
    t0 = time.perf_counter()
    first = demo_scene(0.0)  # the studio through each lens once, then only what the moving ball changes
    stills = render_views(dataclasses.replace(first, objects=tuple(o for o in first.objects if o is not ball(first))),
                          list(rig.cameras))
    images = [[render_moved(demo_scene(f / frames), still, ball(demo_scene(f / frames))) for still in stills]
              for f in range(frames)]
    print(f"rendered {frames} HD frame sets in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    undistort = undistortion_cost(images[0])
    print(f"undistortion: {undistort}", file=sys.stderr)
    results: dict = {"undistortion": undistort, "setup": {
        "cameras": 8, "camera_size": f"{HD_SIZE[0]}x{HD_SIZE[1]}", "distortion": list(HD_DIST), "frames": frames,
        "view": f"{HD_VIEW[0]}x{HD_VIEW[1]}", "planes": PLANES, "method": "kojima", "coarse_to_fine": True,
        "seconds_per_config": seconds, "load_average_before": load_before}}
    with tempfile.TemporaryDirectory(prefix="sweepcast-bench-") as tmp:
        tmp = Path(tmp)
        files = []
        for c, cam in enumerate(rig.cameras):
            path = tmp / f"{cam.name}.mp4"
            with H264Writer(path, *HD_SIZE, 30.0, crf=16) as w:
                for f in range(frames):
                    w.write(images[f][c])
            files.append(("videos", (path.name, path.read_bytes(), "video/mp4")))
            files.append(("backgrounds", (f"{cam.name}.png", cv2.imencode(".png", stills[c].background)[1].tobytes(),
                                          "image/png")))
        upload_mb = sum(len(f[1][1]) for f in files) / 2**20
        log = tmp / "server.log"
        with serve_app({"SWEEPCAST_DATA_DIR": str(tmp / "data"), "SWEEPCAST_DEMO_RIG": "false"}, log=log) as app:
            with httpx.Client(base_url=app.base, timeout=600) as http:
                rig_id = http.post("/v1/rigs", files={"files": ("rig.json", json.dumps(rig_to_dict(rig)).encode())}
                                   ).json()["id"]
                t0 = time.perf_counter()
                r = http.post(f"/v1/rigs/{rig_id}/recordings", files=files)
                if r.status_code != 202:
                    raise SystemExit(f"the HD recording was refused: {r.status_code} {r.text}")
                rec_id = r.json()["id"]

                def ready():
                    rec = http.get(f"/v1/rigs/{rig_id}/recordings/{rec_id}").json()
                    if rec["state"] == "failed":
                        raise SystemExit(f"the HD import failed: {rec['error']}")
                    return rec if rec["state"] == "ready" else None

                rec = wait_for(ready, 1800, "the HD recording", app.proc, log)
                import_s = time.perf_counter() - t0
            results["import"] = {"seconds": import_s, "upload_mb": upload_mb, "frames": rec["frames"],
                                 "fps": rec["fps"], "background": rec["background"]}
            print(f"HD import: {import_s:.1f} s for {upload_mb:.0f} MB", file=sys.stderr)
            url = f"{app.base.replace('http', 'ws')}/v1/rigs/{rig_id}/view?source={rec_id}"
            asyncio.run(first_frame(url))
            results["viewer"] = {
                "orbit": asyncio.run(run_config(url, 1, HD_VIEW, seconds, app.proc.pid)),
                "playing": asyncio.run(run_config(url, 1, HD_VIEW, seconds, app.proc.pid, frames=frames)),
            }
            for k, v in results["viewer"].items():
                print(f"HD {k} at 640x360: {v['fps']:.1f} fps, p95 {v['latency_p95_ms']:.0f} ms", file=sys.stderr)
            # the session's cost per new frame set, in this process on the stored archive
            store = open_store((tmp / "data" / "blobs").resolve().as_uri())
            archive = Archive(store.local_path(archive_key(rec_id)))
            k = source_factor(rig, *HD_VIEW)
            small = shrunk_rig(rig, k)
            renderer = SweepRenderer(small, shrunk_images(archive.frame_set(0), small),
                                     backgrounds=shrunk_images(archive.backgrounds(), small))
            full = archive.frame_set(1)
            shrunk = shrunk_images(full, small)
            results["frame_set"] = {
                "source_factor": k,
                "decode_ms": median_ms(lambda: archive.frame_set(1), 5),
                "shrink_ms": median_ms(lambda: shrunk_images(full, small), 5),
                "set_frames_ms": median_ms(lambda: renderer.set_frames(shrunk), 5),
            }
            archive.close()
    return results, hd_markdown(results)


def hd_markdown(results: dict) -> str:
    u, imp, fs, st = results["undistortion"], results["import"], results["frame_set"], results["setup"]
    viewers = results["viewer"]
    rows = [[k, v["fps"], v["latency_p50_ms"], v["latency_p95_ms"], v["render_p50_ms"], v["server_cpu_cores"]]
            for k, v in viewers.items()]
    return (
        f"Undistortion at `set_frames` (10 cameras {u['size']}, OpenCV distortion {tuple(st['distortion'])}, "
        f"bilinear remap of precomputed float maps): **{u['remap_ms']:.0f} ms per frame set** for the remaps alone; "
        f"`set_frames` {u['set_frames_ms']:.0f} ms with distortion against {u['set_frames_pinhole_ms']:.0f} ms for "
        f"the same rig without (difference {u['undistortion_ms']:.0f} ms).\n\n"
        f"HD recording: {st['cameras']} cameras {st['camera_size']} with that distortion, {imp['frames']} frames of "
        f"the studio rendered through the lens, H.264 videos + empty-studio PNGs ({imp['upload_mb']:.0f} MB) imported "
        f"through `POST /v1/rigs/{{id}}/recordings` with the default limits: ready after {imp['seconds']:.1f} s.\n\n"
        f"One closed-loop viewer at {st['view']} ({st['planes']} planes, Kojima, coarse-to-fine, 5x5 window, "
        f"visual hull): the session renders from frames shrunk {fs['source_factor']}x. \"orbit\": a new pose every "
        f"view on frame 0; \"playing\": also a new frame every view (the session shrinks each frame once and keeps it: "
        f"after the first pass over the {st['frames']} frames a new frame costs only its `set_frames`). "
        f"Load average before the run: {st['load_average_before']:.2f}.\n\n"
        + md_table(["viewer", "fps", "latency p50 ms", "latency p95 ms", "session render p50 ms", "server CPU cores"],
                   rows)
        + f"\n\nPer new frame set in the session: decode 8 PNGs {fs['decode_ms']:.0f} ms, shrink {fs['shrink_ms']:.0f} "
        f"ms, `set_frames` at {HD_VIEW[0]}x{HD_VIEW[1]} (undistortion, silhouettes, packing) "
        f"{fs['set_frames_ms']:.1f} ms. Target (orbit): >= 10 fps: "
        f"{'met' if viewers['orbit']['fps'] >= 10 else 'not met'}.\n"
    )


# --- live camera streams --------------------------------------------------------------------------------
LIVE_SETS = 6
LIVE_VIEW = (320, 240)
LIVE_TARGET = {"ingest_sets_per_s": 15.0, "viewer_fps": 15.0}


def live_frame_sets(rig: Rig, sets: int, quality: int = 90) -> tuple[list[bytes], list[list[bytes]]]:
    """JPEGs of the empty studio (the background set) and of ``sets`` frame sets of the demo scene (its ball
    moving), one per camera of ``rig``."""
    import dataclasses

    from workers.streaming.demo import demo_ball, demo_scene
    from workers.synth import render_moved, render_views

    def jpeg(img: np.ndarray) -> bytes:
        return cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])[1].tobytes()

    first = demo_scene(0.0)
    k, _ = demo_ball(first)
    stills = render_views(dataclasses.replace(first, objects=first.objects[:k] + first.objects[k + 1:]),
                          list(rig.cameras))
    frames = []
    for f in range(sets):
        scene = demo_scene(f / (4 * sets))
        frames.append([jpeg(render_moved(scene, still, demo_ball(scene)[1])) for still in stills])
    return [jpeg(s.background) for s in stills], frames


def frame_set_message(jpegs: list[bytes], seq: int, background: bool = False) -> bytes:
    from workers.streaming.framing import pack_message

    return pack_message({"sizes": [len(j) for j in jpegs], "seq": seq, "background": background}, jpegs)


async def pusher(url: str, sets: list[list[bytes]], start: asyncio.Event, stop: asyncio.Event) -> dict:
    """Closed-loop ingest: the next frame set as soon as the previous one is acknowledged."""
    async with websockets.connect(url, max_size=None) as ws:
        json.loads(await ws.recv())  # hello
        await start.wait()
        acks, latencies, seq = [], [], 0
        t0 = time.perf_counter()
        while not stop.is_set():
            seq += 1
            t = time.perf_counter()
            await ws.send(frame_set_message(sets[seq % len(sets)], seq))
            reply = json.loads(await ws.recv())
            if reply.get("type") != "ack":
                raise RuntimeError(f"frame set {seq}: {reply}")
            latencies.append((time.perf_counter() - t) * 1e3)
            acks.append(reply)
        wall = time.perf_counter() - t0
    return {"sets": len(acks), "seconds": wall, "latencies": latencies, "acks": acks}


async def live_viewer(url: str, start: asyncio.Event, stop: asyncio.Event, phase: float,
                      counted: bool = True) -> dict:
    """Closed-loop viewer of the live source: renders before ``start`` are warm-up, those received
    between ``start`` and ``stop`` count (``counted`` False: one view, nothing counted)."""
    async with websockets.connect(url, max_size=None) as ws:
        while json.loads(await ws.recv())["type"] != "ready":
            pass
        latencies, renders, seqs, i = [], [], set(), 0
        t0 = None
        while i == 0 or not stop.is_set():
            i += 1
            msg = {**view_message(i, phase, LIVE_VIEW), "frame": "live"}
            t = time.perf_counter()
            await ws.send(json.dumps(msg))
            while True:
                message = await ws.recv()
                if isinstance(message, bytes):
                    header, _ = unpack_message(message)
                    if header["id"] == i:
                        break
                elif json.loads(message).get("type") == "error":
                    raise RuntimeError(message)
            if t0 is not None and not stop.is_set():
                latencies.append((time.perf_counter() - t) * 1e3)
                renders.append(header["render_ms"])
                seqs.add(header["seq"])
            elif start.is_set() and t0 is None:
                t0 = time.perf_counter()
        wall = time.perf_counter() - t0 if t0 is not None else float("nan")
    if not counted:
        return {}
    if not latencies:
        raise SystemExit("a live viewer received no frame within the measurement: give --seconds more")
    return {"fps": len(latencies) / wall, "latency_p50_ms": float(np.percentile(latencies, 50)),
            "latency_p95_ms": float(np.percentile(latencies, 95)), "render_p50_ms": float(np.median(renders)),
            "live_sets_seen": len(seqs)}


async def live_config(base: str, rig_id: str, sets: list[list[bytes]], viewers: int, ingest: bool, seconds: float,
                      server_pid: int) -> dict:
    """Ingest and/or ``viewers`` viewers for ``seconds``; ingest figures, each viewer's, server cores."""
    ws = base.replace("http", "ws")
    start, stop = asyncio.Event(), asyncio.Event()
    push_task = asyncio.create_task(pusher(f"{ws}/v1/rigs/{rig_id}/live", sets, start, stop)) if ingest else None
    view_tasks = [asyncio.create_task(live_viewer(f"{ws}/v1/rigs/{rig_id}/view?source=live", start, stop,
                                                  80.0 * k / viewers))
                  for k in range(viewers)]
    await asyncio.sleep(3.0)  # sockets open, viewers past their first frames
    cpu0, t0 = tree_cpu_seconds(server_pid), time.perf_counter()
    start.set()
    await asyncio.sleep(seconds)
    stop.set()
    out: dict = {"server_cpu_cores": 0.0, "viewers": [await t for t in view_tasks]}
    out["server_cpu_cores"] = (tree_cpu_seconds(server_pid) - cpu0) / (time.perf_counter() - t0)
    if push_task is not None:
        p = await push_task
        acks = p["acks"]
        out["ingest"] = {
            "sets_per_s": p["sets"] / p["seconds"], "ack_p50_ms": float(np.percentile(p["latencies"], 50)),
            "ack_p95_ms": float(np.percentile(p["latencies"], 95)), "sets": p["sets"],
            "dropped": acks[-1]["dropped"] if acks else 0,
            **{f"{k}_p50": float(np.median([a.get(k, np.nan) for a in acks]))
               for k in ("decode_ms", "apply_ms", "lock_wait_ms")},
            "source_factor": acks[-1].get("source_factor") if acks else None,
        }
    return out


def live(args: argparse.Namespace) -> tuple[dict, str]:
    """The part ``live`` (the module docstring): frame sets pushed over the live socket while viewers render."""
    from workers.streaming.demo import demo_rig
    from workers.sweep.rig_io import rig_to_dict

    import pickle

    seconds, viewers = seconds_per_config(args), args.viewers_live
    load_before = os.getloadavg()[0]
    rig = demo_rig()
    t0 = time.perf_counter()
    cache = Path(tempfile.gettempdir()) / f"sweepcast-bench-live-{LIVE_SETS}.pickle"  # the inputs only: minutes to render
    if cache.exists():
        background, sets = pickle.loads(cache.read_bytes())
    else:
        background, sets = live_frame_sets(rig, LIVE_SETS)
        cache.write_bytes(pickle.dumps((background, sets)))
    print(f"rendered {LIVE_SETS} frame sets in {time.perf_counter() - t0:.0f} s; "
          f"{np.mean([sum(map(len, s)) for s in sets]) / 1e3:.0f} KB per set", file=sys.stderr)
    results: dict = {"setup": {
        "cameras": len(rig), "camera_size": "640x480", "jpeg_kb_per_set": float(np.mean([sum(map(len, s)) for s in sets]) / 1e3),
        "view": f"{LIVE_VIEW[0]}x{LIVE_VIEW[1]}", "planes": PLANES, "method": "kojima", "coarse_to_fine": True,
        "visual_hull": True, "viewers": viewers, "seconds_per_config": seconds, "load_average_before": load_before}}
    with tempfile.TemporaryDirectory(prefix="sweepcast-bench-") as tmp:
        log = Path(tmp) / "server.log"
        # steady state: the checkout's kernel cache (make's install filled it), not compiled on the clock
        env = {"SWEEPCAST_DATA_DIR": str(Path(tmp) / "data"), "SWEEPCAST_DEMO_RIG": "false",
               "SWEEPCAST_NUMBA_CACHE_DIR": str(CHECKOUT_KERNEL_CACHE)}
        with serve_app(env, log=log) as app:
            with httpx.Client(base_url=app.base, timeout=60) as http:
                rig_id = http.post("/v1/rigs", files={"files": ("rig.json", json.dumps(rig_to_dict(rig)).encode())}
                                   ).json()["id"]

            async def prime() -> None:  # background set, a frame set, a first view: the session is made and warm
                async with websockets.connect(f"{app.base.replace('http', 'ws')}/v1/rigs/{rig_id}/live",
                                              max_size=None) as ws:
                    json.loads(await ws.recv())
                    for seq, (jpegs, flag) in enumerate([(background, True), (sets[0], False)], 1):
                        await ws.send(frame_set_message(jpegs, seq, flag))
                        reply = json.loads(await ws.recv())
                        if reply.get("type") != "ack":
                            raise SystemExit(f"the live socket refused a set: {reply}")
                stop = asyncio.Event()
                stop.set()
                await live_viewer(f"{app.base.replace('http', 'ws')}/v1/rigs/{rig_id}/view?source=live", stop, stop,
                                  0.0, counted=False)

            asyncio.run(prime())
            configs = {"viewer alone": (viewers, False), "ingest alone": (0, True), "ingest + viewers": (viewers, True)}
            for name, (n, ingest) in configs.items():
                r = asyncio.run(live_config(app.base, rig_id, sets, n, ingest, seconds, app.proc.pid))
                results[name] = r
                line = f"{name}: server {r['server_cpu_cores']:.2f} cores"
                if "ingest" in r:
                    line += (f"; ingest {r['ingest']['sets_per_s']:.1f} sets/s, ack p95 {r['ingest']['ack_p95_ms']:.0f} ms"
                             f" (decode {r['ingest']['decode_ms_p50']:.0f} ms, apply {r['ingest']['apply_ms_p50']:.0f} ms)")
                for v in r["viewers"]:
                    line += f"; viewer {v['fps']:.1f} fps p95 {v['latency_p95_ms']:.0f} ms"
                print(line, file=sys.stderr)
    results["in_process"] = live_set_costs(rig, background, sets)
    print(f"in process, per set: {results['in_process']}", file=sys.stderr)
    both = results["ingest + viewers"]
    results["target"] = {**LIVE_TARGET, "met": both["ingest"]["sets_per_s"] >= LIVE_TARGET["ingest_sets_per_s"]
                         and min(v["fps"] for v in both["viewers"]) >= LIVE_TARGET["viewer_fps"]}
    results["load_average_after"] = os.getloadavg()[0]
    return results, live_markdown(results)


def live_set_costs(rig: Rig, background: list[bytes], sets: list[list[bytes]], repeats: int = 5) -> dict:
    """CPU ms per frame set in this process (numba's threads included; medians over passes through ``sets``):
    decoding at full size (the anchor: what the session did before decoding at the viewers' size), decoding
    at half size (DCT scaling, what a 320x240 viewer needs of 640x480 cameras), and applying a decoded set
    (background model, silhouettes, renderer frames)."""
    from workers.streaming.images import decode_image
    from workers.streaming.session import LiveSession, SessionLimits

    live = LiveSession(rig, SessionLimits())
    live.push(background, True)
    live.view("bench", Viewpoint(frame="live", width=LIVE_VIEW[0], height=LIVE_VIEW[1], planes=PLANES))
    decoded = [live.decode(s) for s in sets]

    def per_set(fn) -> float:
        passes = []
        for _ in range(repeats):
            t = time.process_time()
            for i, s in enumerate(sets):
                fn(i, s)
            passes.append((time.process_time() - t) * 1e3 / len(sets))
        return float(statistics.median(passes))

    return {
        "decode_full_ms": per_set(lambda i, s: [decode_image(d, (c.width, c.height)) for c, d in zip(rig.cameras, s)]),
        "decode_reduced_ms": per_set(lambda i, s: live.decode(s)),
        "apply_ms": per_set(lambda i, s: live.apply(decoded[i], s)),
        "source_factor": live.source_factor,
    }


def live_markdown(results: dict) -> str:
    st, t, ip = results["setup"], results["target"], results["in_process"]
    rows = []
    for name in ("viewer alone", "ingest alone", "ingest + viewers"):
        r = results[name]
        ing = r.get("ingest")
        vs = r["viewers"]
        rows.append([name, ing["sets_per_s"] if ing else "-", ing["ack_p50_ms"] if ing else "-",
                     ing["ack_p95_ms"] if ing else "-", ing["decode_ms_p50"] if ing else "-",
                     ing["apply_ms_p50"] if ing else "-",
                     min(v["fps"] for v in vs) if vs else "-", max(v["latency_p95_ms"] for v in vs) if vs else "-",
                     r["server_cpu_cores"]])
    return (
        f"Live camera streams: {st['cameras']} cameras {st['camera_size']} (the demo rig), JPEG frame sets of the studio "
        f"with its moving ball ({st['jpeg_kb_per_set']:.0f} KB per set) pushed over `/v1/rigs/{{id}}/live` closed-loop "
        f"(the next set when the previous is acknowledged) while {st['viewers']} viewer(s) on `?source=live` render "
        f"{st['view']} views closed-loop ({st['planes']} planes, Kojima, coarse-to-fine, visual hull from the live "
        f"background model). {st['seconds_per_config']:g} s per configuration. The session decodes each set at the "
        "size its viewers need (JPEG DCT scaling; `source_factor` in the ack) before taking the render lock. "
        + load_note(st["load_average_before"], results["load_average_after"]) + "\n\n"
        + md_table(["configuration", "ingest sets/s", "ack p50 ms", "ack p95 ms", "decode ms/set", "apply ms/set",
                    "viewer fps (min)", "viewer p95 ms (max)", "server CPU cores"], rows)
        + f"\n\nPer frame set in this process (CPU ms, numba's threads included): decoding the 10 JPEGs at full size "
        f"{ip['decode_full_ms']:.1f} (the anchor), at the viewer's size (factor {ip['source_factor']}, DCT scaling) "
        f"{ip['decode_reduced_ms']:.1f}; applying a decoded set (background model, silhouettes, renderer frames) "
        f"{ip['apply_ms']:.1f}."
        + f"\n\nTarget: >= {t['ingest_sets_per_s']:g} sets/s ingested while each viewer gets >= {t['viewer_fps']:g} "
        f"fps: **{'met' if t['met'] else 'not met'}**." + ("" if t["met"] else " " + live_limit(results)) + "\n"
    )


def live_limit(results: dict) -> str:
    """What the target costs in CPU, from this run's own figures."""
    t, alone, ingest = results["target"], results["viewer alone"], results["ingest alone"]
    view_ms = alone["server_cpu_cores"] * 1e3 / sum(v["fps"] for v in alone["viewers"])
    set_ms = ingest["server_cpu_cores"] * 1e3 / ingest["ingest"]["sets_per_s"]
    n = results["setup"]["viewers"]
    need = (t["ingest_sets_per_s"] * set_ms + n * t["viewer_fps"] * view_ms) / 1e3
    return (f"Limit: CPU. The server spends {set_ms:.0f} ms of CPU per frame set ingested (receiving, decoding, "
            f"applying, storing; 'ingest alone') and {view_ms:.0f} ms per view ('viewer alone'), so the target "
            f"takes {need:.1f} cores; this machine has {os.cpu_count()}.")


def seconds_per_config(args: argparse.Namespace) -> float:
    """Measurement time per configuration: ``--seconds``, else 5 s with ``--quick``, else 15 s."""
    return args.seconds or (5.0 if args.quick else 15.0)


sections = Sections("streaming", __doc__)
sections.parser.add_argument("--quick", action="store_true", help="5 s per configuration instead of 15")
sections.parser.add_argument("--seconds", type=float, help="measurement time per configuration")
sections.parser.add_argument("--viewers", type=int, nargs="+", default=list(VIEWERS),
                             help=f"viewers: viewer counts (default {' '.join(map(str, VIEWERS))})")
sections.parser.add_argument("--sizes", nargs="+", default=[f"{w}x{h}" for w, h in SIZES],
                             help="viewers: view sizes WxH (default 320x240 640x480)")
sections.parser.add_argument("--planes", type=int, default=PLANES, help=f"viewers: depth planes (default {PLANES})")
sections.parser.add_argument("--quiet", type=float, help="viewer_sizes: before each size wait (up to 3 min) for the "
                                                         "1-minute load average to fall under this")
sections.parser.add_argument("--hd-frames", type=int, default=6, help="hd: frames of the HD recording (default 6)")
sections.parser.add_argument("--viewers-live", type=int, default=1, help="live: viewers on the live source (default 1)")
sections.part("viewers", "concurrent viewers of the demo at each size (another grid: streaming_viewers[_pN])",
              bench_viewers, results=viewers_results)
sections.part("viewer_sizes", "one viewer at each candidate size: the viewer's default size", viewer_sizes,
              results="streaming_viewer_size")
sections.part("hd", "undistortion cost and an HD 8-camera recording at 640x360", hd)
sections.part("live", "live ingest of 10 x 640x480 JPEG cameras with viewers", live)


if __name__ == "__main__":
    with exit_on_sigterm():  # SIGTERM unwinds the serve_app block, which stops the server and its Ray
        raise SystemExit(sections.main())
