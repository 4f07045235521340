"""Cold start: what a new user waits for, against the same work warm, in the same run.

1. Kernels (each engine's numba code, :mod:`workers.warmup`): in a fresh process with an empty cache
   (compile) and in a fresh process with the cache the first one wrote (load), seconds per engine.
2. First calls a user makes in a fresh worker process: a bundle adjustment (synthetic, 6 cameras x 250
   points) and the drone pipeline (a generated 36-frame 320x240 flight video), each timed as the first
   call of a process with an empty cache ("cold"), the first call of a process with a warm cache
   ("warm start") and the second call of that process ("steady").
3. The service as a new user starts it: ``python -m app serve`` on a fresh data folder whose kernel cache
   and demo-recording cache the first ``make serve`` filled (``sweepcast warmup``, timed), no demo rig yet; again on
   the same folder (a restart); and on a fresh folder with an empty cache (a start that skipped the
   warm-up, e.g. a bare ``pip install``): seconds from the process start to
   ``/readyz`` 200, to the demo recording ready and to the kernels' warm-up done (background); the
   first viewer frame (320x240, 48 planes) after ready and after the recording is ready; then the first
   photo's orientation (a real face photo) and the first reconstruction job (the generated flight).

Run: ``python benchmarks/coldstart.py`` from the repository root (about 12 minutes on 2 cores).
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import websockets

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import md_table, publish  # noqa: E402
from benchmarks.streaming import cpu_seconds, demo_recording, view_message, wait_for  # noqa: E402
from tests.servers import serve_app  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
GOALS = {"ready_s": 5.0, "first_frame_after_ready_s": 3.0, "request_compile_s": 3.0}

# --- 1 and 2: in fresh processes ----------------------------------------------------------------------
_FIRST_CALLS = r"""
import json, sys, time
import numpy as np
sys.path.insert(0, {root!r})
from tests.drone.test_bundle import _problem, K
from workers.drone import bundle
from workers.drone.camera_models import PinholeModel, pose_params
from workers.drone.calibration import from_values
from workers.drone.params import ReconstructionParams
from workers.drone.reconstruction import reconstruct

def ba():
    R, t, X, ci, pj, obs = _problem()
    params = pose_params(R, t) + np.r_[np.zeros(6), np.full(30, 0.01)].reshape(6, 6)
    fixed = np.zeros((6, 6), bool); fixed[0] = True; fixed[1, 3:] = True
    bundle.solve(PinholeModel(K, 6), params, X + 0.05, ci, pj, obs, fixed, bundle.BAOptions(max_iterations=50))

def drone():
    k = json.loads({intrinsics!r})
    reconstruct({video!r}, from_values(k["fx"], k["fy"], k["cx"], k["cy"]), ReconstructionParams(max_features=1000),
                lambda f, s: None)

fn = {{"bundle_adjustment": ba, "drone_pipeline": drone}}[sys.argv[1]]
times = []
for _ in range(2):
    t0 = time.perf_counter(); fn(); times.append(time.perf_counter() - t0)
print(json.dumps(times))
"""


def _python(code_or_args: list[str], cache: Path) -> str:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    done = subprocess.run([sys.executable, *code_or_args], cwd=ROOT, env=env, capture_output=True, text=True,
                          check=True)
    return done.stdout.strip().splitlines()[-1]


def kernels(tmp: Path) -> dict:
    """Per engine, one process compiling after the other (``--jobs 1``): compile and load seconds."""
    cache = tmp / "kernels-cache"
    cold = json.loads(_python(["-m", "workers.warmup", "--jobs", "1"], cache))
    warm = json.loads(_python(["-m", "workers.warmup", "--jobs", "1"], cache))
    return {name: {"compile_s": cold[name], "cached_s": warm.get(name)} for name in cold}


_RAY_START = r"""
import json, sys, time
t0 = time.monotonic()
import ray
t1 = time.monotonic()
sys.path.insert(0, {root!r})
from app.raycluster import connect
connect(None)
print(json.dumps({{"import_s": t1 - t0, "init_s": time.monotonic() - t1}}))
ray.shutdown()
"""


def ray_start() -> dict:
    """Seconds to import ray and to start a local Ray the way the service does, in a fresh process."""
    done = subprocess.run([sys.executable, "-c", _RAY_START.format(root=str(ROOT))], cwd=ROOT, check=True,
                          capture_output=True, text=True, env={**os.environ, "RAY_USAGE_STATS_ENABLED": "0",
                                                                "RAY_AUTH_MODE": "disabled"})
    return json.loads(done.stdout.strip().splitlines()[-1])


def install_warmup(data_dir: Path) -> tuple[float, float]:
    """The first ``make serve``'s warm-up (``sweepcast warmup``: kernels compiled in one process per core into
    ``data_dir``'s empty cache, then the demo recording rendered into its cache); wall seconds of all of it, and
    of the recording."""
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "SWEEPCAST_NUMBA_CACHE_DIR")}
    t0 = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "app", "warmup", "--data-dir", str(data_dir)], cwd=ROOT, env=env,
                          check=True, capture_output=True, text=True)
    return time.monotonic() - t0, json.loads(done.stdout.strip().splitlines()[-1])["demo_recording"]


def first_calls(tmp: Path, flight: tuple[Path, dict]) -> dict:
    """Each work in its own process: with an empty cache, then with the cache ``workers.warmup`` wrote (the
    service's path: this also checks that the warm-up compiles what the work uses)."""
    code = _FIRST_CALLS.format(root=str(ROOT), video=str(flight[0]), intrinsics=json.dumps(flight[1]))
    warmed = tmp / "warmed-cache"
    _python(["-m", "workers.warmup"], warmed)
    out = {}
    for name in ("bundle_adjustment", "drone_pipeline"):
        cold = json.loads(_python(["-c", code, name], tmp / f"empty-cache-{name}"))
        warm = json.loads(_python(["-c", code, name], warmed))
        out[name] = {"cold_s": cold[0], "warm_start_s": warm[0], "steady_s": warm[1]}
    return out


def make_flight(tmp: Path) -> tuple[Path, dict]:
    from workers.synth.flight import encode_video, flight_cameras, render_flight, terrain_scene

    cams = flight_cameras(36, length=30.0, altitude=25.0, sway=3.0, width=320, height=240, fov_deg=70,
                          shake_deg=0.2, seed=3)
    frames = render_flight(terrain_scene(3, extent=80.0, n_buildings=10, n_trees=12), cams)
    K = cams[0].K
    path = encode_video(frames, tmp / "flight.mp4", fps=25)
    return path, {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}


# --- 3: the service -------------------------------------------------------------------------------------
async def _first_frame(url: str) -> None:
    async with websockets.connect(url, max_size=None) as ws:
        await ws.send(json.dumps(view_message(1, 0.0, (320, 240))))
        while True:
            message = await ws.recv()
            if isinstance(message, bytes):
                return
            if json.loads(message).get("type") == "error":
                raise SystemExit(f"the viewer got an error: {message}")


def _job_done(http: httpx.Client, job_id: str) -> bool:
    state = http.get(f"/v1/jobs/{job_id}").json()["state"]
    if state == "failed":
        raise SystemExit(f"job {job_id} failed")
    return state == "succeeded"


def service_start(data_dir: Path, log: Path, photo: bytes, flight: tuple[Path, dict]) -> dict:
    t0 = time.monotonic()
    with serve_app({"SWEEPCAST_DATA_DIR": str(data_dir), "NUMBA_CACHE_DIR": None,
                    "SWEEPCAST_WARM_KERNELS": "true"}, log=log, wait=False) as app:
        answering = wait_for(lambda: httpx.get(f"{app.base}/healthz", timeout=2).status_code == 200
                             and time.monotonic() - t0, 300, "the server to answer", app.proc, log)
        app.wait_ready(300)
        ready = time.monotonic() - t0
        out = {"answering_s": answering, "ready_s": ready, "cpu_at_ready_s": cpu_seconds(app.proc.pid)}
        if httpx.get(f"{app.base}/readyz", timeout=10).json()["checks"]["kernels"]["state"] != "warming":
            out["kernels_warm_s"] = ready  # no warm-up to wait for (a stamped cache) or already over
        with httpx.Client(base_url=app.base, timeout=120) as http:
            rig_id, recording = wait_for(lambda: demo_recording(http), 900, "the demo recording", app.proc, log)
            out["demo_ready_s"] = time.monotonic() - t0
            t = time.monotonic()
            asyncio.run(_first_frame(f"{app.base.replace('http', 'ws')}/v1/rigs/{rig_id}/view?source={recording['id']}"))
            out["first_frame_s"] = time.monotonic() - t
            out["first_frame_after_ready_s"] = time.monotonic() - t0 - ready
            t = time.monotonic()
            r = http.post("/v1/photos/orientation", files={"file": ("face.jpg", photo, "image/jpeg")})
            r.raise_for_status()
            out["first_photo_s"] = time.monotonic() - t
            t = time.monotonic()
            job = http.post("/v1/reconstructions", files={"media": ("flight.mp4", flight[0].read_bytes(), "video/mp4")},
                            data={"params": json.dumps({**flight[1], "max_features": 1000})}).json()
            wait_for(lambda: _job_done(http, job["id"]), 600, "the reconstruction", app.proc, log)
            out["first_reconstruction_s"] = time.monotonic() - t
            kernels = wait_for(lambda: (k := http.get("/readyz").json()["checks"]["kernels"])["state"] != "warming"
                               and k, 900, "the kernel warm-up", app.proc, log)
            out.setdefault("kernels_warm_s", time.monotonic() - t0)  # an upper bound: checked after the work above
            out["kernels"] = kernels
    return out


def service(tmp: Path, flight: tuple[Path, dict]) -> dict:
    from workers.common.datasets import data_root

    face = next(iter(sorted((data_root() / "faces" / "dev").rglob("*.jpg"))), None)
    photo = face.read_bytes() if face is not None else _synthetic_photo()
    data_dir = tmp / "service-data"
    install_s, demo_s = install_warmup(data_dir)
    return {"install_warmup_s": install_s, "install_demo_recording_s": demo_s,
            "first_start": service_start(data_dir, tmp / "first.log", photo, flight),
            "restart": service_start(data_dir, tmp / "restart.log", photo, flight),
            "empty_cache": service_start(tmp / "bare-data", tmp / "bare.log", photo, flight)}


def _synthetic_photo() -> bytes:
    import cv2
    import numpy as np

    return cv2.imencode(".jpg", np.random.default_rng(0).integers(0, 256, (480, 640, 3), np.uint8))[1].tobytes()


def markdown(r: dict) -> str:
    rows = [[name, f"{v['compile_s']:.1f}", f"{v['cached_s']:.2f}"] for name, v in r["kernels"].items()]
    load = r["load_average_before"]
    parts = [f"Load average before the run {load:.2f} on {os.cpu_count()} cores"
             + (" (other work shared the CPU: every figure here is high)" if load > 0.5 else "") + ".", "",
             "Kernels, each engine's warm-up (`workers.warmup`) in a fresh process: with an empty cache, and with "
             "the cache the first process wrote.", "", md_table(["engine", "compile (s)", "from cache (s)"], rows), ""]
    rows = [[name, f"{v['cold_s']:.2f}", f"{v['warm_start_s']:.2f}", f"{v['steady_s']:.2f}"]
            for name, v in r["first_calls"].items()]
    parts += ["First calls in a fresh worker process (synthetic BA 6 cameras x 250 points; drone pipeline on a "
              "36-frame 320x240 generated flight): empty cache, warm cache, and the second call.", "",
              md_table(["work", "cold (s)", "warm start (s)", "steady (s)"], rows), ""]
    keys = [("answering_s", "`/healthz` 200 after start (the API answers)"), ("ready_s", "`/readyz` 200 after start"), ("kernels_warm_s", "kernel warm-up done after start (at ready: none needed; else seen after the work below)"),
            ("demo_ready_s", "demo recording ready after start"),
            ("first_frame_after_ready_s", "first viewer frame after ready (includes waiting for the demo recording)"),
            ("first_frame_s", "first viewer frame after the recording is ready"),
            ("first_photo_s", "then: the first photo's orientation"),
            ("first_reconstruction_s", "then: the first reconstruction (36 frames)")]
    sv = r["service"]
    rows = [[label, f"{sv['first_start'][k]:.1f}", f"{sv['restart'][k]:.1f}", f"{sv['empty_cache'][k]:.1f}",
             f"<= {GOALS[k]:.0f}" if k in GOALS else ""] for k, label in keys]
    parts += [f"`python -m app serve` as a new user starts it: on a fresh data folder (no demo rig) whose kernel "
              f"cache the first `make serve` filled before starting it (`sweepcast warmup`, kernels in one process "
              f"per core, then the demo recording into the folder's `cache/demo`, which the service publishes as "
              f"the demo's recording: "
              f"**{sv['install_warmup_s']:.1f} s**, of it {sv['install_demo_recording_s']:.1f} s the recording), "
              "then restarted on the same folder; and on a fresh folder with empty caches (`sweepcast serve` "
              "without that warm-up: kernels compile in the background while requests come, the demo job renders "
              "its recording); seconds.", "",
              md_table(["", "first start after the warm-up", "restart", "first start, empty cache", "goal"], rows), ""]
    first, again = sv["first_start"], sv["restart"]
    if max(first["first_frame_after_ready_s"], again["first_frame_after_ready_s"]) > GOALS["first_frame_after_ready_s"]:
        parts += [f"First viewer frame on the first start: {first['first_frame_after_ready_s']:.1f} s after ready, of "
                  f"which {max(first['demo_ready_s'] - first['ready_s'], 0.0):.1f} s wait for the demo recording (10 "
                  "cameras x 12 frames of the studio: the service publishes the one the warm-up kept, before Ray is "
                  f"up; a job on Ray renders it when none was kept), then {first['first_frame_s']:.1f} s for the frame: "
                  "the viewer's session actor, a new Ray worker process that imports the renderer, loads its "
                  "kernels from the cache (numba sets up its CPU target on the first) and renders. A restart keeps "
                  f"the recording and shows its first frame {again['first_frame_after_ready_s']:.1f} s after ready.",
                  ""]
    if max(sv["first_start"]["ready_s"], sv["restart"]["ready_s"]) > GOALS["ready_s"]:
        ray = r["ray_start"]
        parts += [f"Readiness waits for Ray: the API answers {sv['restart']['answering_s']:.1f} s after a restart, and "
                  f"a local Ray started alone in a fresh process (`ray.init` as the service calls it, after "
                  f"{ray['import_s']:.1f} s of importing ray) takes **{ray['init_s']:.1f} s** on this machine: its "
                  "GCS, raylet and their agents are processes that start and register one after the other. The "
                  "service starts Ray first and imports itself meanwhile (`raycluster.start_connecting`). Limit: "
                  f"CPU. By `/readyz` 200 the service's processes (the API's imports, Ray's processes, most of them "
                  f"Python importing ray, and the kernel warm-up where the cache was not stamped current) had used {again['cpu_at_ready_s']:.1f} CPU-seconds on a "
                  f"restart ({first['cpu_at_ready_s']:.1f} on the first start): on {os.cpu_count()} cores no less "
                  f"than {again['cpu_at_ready_s'] / (os.cpu_count() or 1):.1f} s.", ""]
    return "\n".join(parts)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skip-service", action="store_true", help="only the in-process parts (1 and 2)")
    args = ap.parse_args()
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="sweepcast-coldstart-") as name:
        tmp = Path(name)
        flight = make_flight(tmp)
        results = {"kernels": kernels(tmp), "first_calls": first_calls(tmp, flight)}
        print(json.dumps(results, indent=1), file=sys.stderr)
        if not args.skip_service:
            results["service"] = service(tmp, flight)
            results["ray_start"] = ray_start()
            print(json.dumps(results["service"], indent=1), file=sys.stderr)
    results["load_average_before"] = load_before
    results["goals"] = GOALS
    if "service" in results:
        publish("coldstart", results, markdown(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
