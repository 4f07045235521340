"""Cold start: what a new user waits for, against the same work warm, in the same run.

1. Kernels (each engine's numba code, :mod:`workers.warmup`): in a fresh process with an empty cache
   (compile) and in a fresh process with the cache the first one wrote (load), seconds per engine.
2. First calls a user makes in a fresh worker process: a bundle adjustment (synthetic, 6 cameras x 250
   points) and the drone pipeline (a generated 36-frame 320x240 flight video), each timed as the first
   call of a process with an empty cache ("cold"), the first call of a process with a warm cache
   ("warm start") and the second call of that process ("steady").
3. The service on each install path, ``python -m app serve`` (each with a user cache of its own, the
   ``XDG_CACHE_HOME`` where the kernels and the demo recording are kept):
   - ``make serve``: the first ``make serve`` fills the user cache (``sweepcast warmup``, timed), then starts the
     service on a fresh data folder (no demo rig yet); then restarted on the same folder;
   - a fresh data folder: another new folder on the same machine (``pip install`` + ``sweepcast serve --data-dir``
     where the service ran before, or kernels compiled ahead);
   - ``pip install`` of the wheel ``make wheel`` builds (``packaging/build-wheel.sh``, timed; it carries the kernels
     compiled for x86-64-v3 and the demo recording) into a new virtual environment, then ``sweepcast serve`` from it
     with a new folder and an empty user cache: the first start on a machine;
   - empty caches without shipped kernels: this checkout with a new folder and an empty user cache (what a CPU
     without x86-64-v3, or another Python or numba than the wheel's, gets: kernels compile in the background
     while requests come, the demo job renders its recording);
   - the Docker image: not run here; its figures come from ``docker/verify-stack.sh`` (a freshly built image on
     empty volumes, ``benchmarks/docker_stack.py``: ``benchmarks/results/docker.json``) when that file is there.
   Each start: seconds from the process start to ``/readyz`` 200, to the demo recording ready and to the kernels'
   warm-up done (background); the first viewer frame (320x240, 48 planes) after ready and after the recording
   is ready; then the first photo's orientation (a real face photo), the first reconstruction job (the generated
   36-frame flight) and a second one (the warm time the first is compared with).

Run: ``python -m benchmarks.coldstart`` from the repository root (about 15 minutes on 2 cores).
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

from benchmarks._report import md_table, prog, publish
from benchmarks._timing import load_note
from harness.proc import tree_cpu_seconds
from benchmarks.streaming import demo_recording, first_frame, wait_for
from harness.servers import serve_app

ROOT = Path(__file__).resolve().parents[1]
GOALS = {"ready_s": 5.0, "first_frame_after_ready_s": 3.0, "request_compile_s": 3.0, "first_reconstruction_x": 2.0}

# --- 1 and 2: in fresh processes ----------------------------------------------------------------------
_FIRST_CALLS = r"""
import json, sys, time
import numpy as np
sys.path.insert(0, {root!r})
from harness.bundle_problem import K, line_of_cameras
from workers.drone import bundle
from workers.drone.camera_models import PinholeModel, pose_params
from workers.drone.calibration import from_values
from workers.drone.params import ReconstructionParams
from workers.drone.reconstruction import reconstruct

def ba():
    R, t, X, ci, pj, obs = line_of_cameras()
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


_CACHE_VARIABLES = ("NUMBA_CACHE_DIR", "SWEEPCAST_NUMBA_CACHE_DIR", "SWEEPCAST_DEMO_CACHE_DIR",
                    "SWEEPCAST_PREBUILT_KERNELS", "NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES")


def install_warmup(data_dir: Path, user_cache: Path) -> tuple[float, float]:
    """The first ``make serve``'s warm-up (``sweepcast warmup``: kernels compiled in one process per core into the
    empty user cache ``user_cache``, then the demo recording rendered into it); wall seconds of all of it, and of
    the recording."""
    env = {k: v for k, v in os.environ.items() if k not in _CACHE_VARIABLES}
    env["XDG_CACHE_HOME"] = str(user_cache)
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
def _job_done(http: httpx.Client, job_id: str) -> bool:
    state = http.get(f"/v1/jobs/{job_id}").json()["state"]
    if state == "failed":
        raise SystemExit(f"job {job_id} failed")
    return state == "succeeded"


def _reconstruct(http: httpx.Client, flight: tuple[Path, dict], app, log: Path) -> float:
    t = time.monotonic()
    job = http.post("/v1/reconstructions", files={"media": ("flight.mp4", flight[0].read_bytes(), "video/mp4")},
                    data={"params": json.dumps({**flight[1], "max_features": 1000})}).json()
    wait_for(lambda: _job_done(http, job["id"]), 600, "the reconstruction", app.proc, log)
    return time.monotonic() - t


def service_start(data_dir: Path, user_cache: Path, log: Path, photo: bytes, flight: tuple[Path, dict],
                  installed: Path | None = None) -> dict:
    """One start of the service with ``data_dir`` and ``user_cache``: this checkout's, or the install in the virtual
    environment ``installed`` (run from a folder outside the checkout)."""
    t0 = time.monotonic()
    env = {**{k: None for k in _CACHE_VARIABLES}, "SWEEPCAST_DATA_DIR": str(data_dir),
           "XDG_CACHE_HOME": str(user_cache), "SWEEPCAST_WARM_KERNELS": "true"}
    where = {} if installed is None else {"python": str(installed / "bin" / "python"), "cwd": data_dir.parent}
    with serve_app(env, log=log, wait=False, **where) as app:
        answering = wait_for(lambda: httpx.get(f"{app.base}/healthz", timeout=2).status_code == 200
                             and time.monotonic() - t0, 300, "the server to answer", app.proc, log)
        app.wait_ready(300)
        ready = time.monotonic() - t0
        out = {"answering_s": answering, "ready_s": ready, "cpu_at_ready_s": tree_cpu_seconds(app.proc.pid)}
        if httpx.get(f"{app.base}/readyz", timeout=10).json()["checks"]["kernels"]["state"] != "warming":
            out["kernels_warm_s"] = ready  # no warm-up to wait for (a stamped cache) or already over
        with httpx.Client(base_url=app.base, timeout=120) as http:
            rig_id, recording = wait_for(lambda: demo_recording(http), 900, "the demo recording", app.proc, log)
            out["demo_ready_s"] = time.monotonic() - t0
            t = time.monotonic()
            asyncio.run(first_frame(f"{app.base.replace('http', 'ws')}/v1/rigs/{rig_id}/view?source={recording['id']}"))
            out["first_frame_s"] = time.monotonic() - t
            out["first_frame_after_ready_s"] = time.monotonic() - t0 - ready
            t = time.monotonic()
            r = http.post("/v1/photos/orientation", files={"file": ("face.jpg", photo, "image/jpeg")})
            r.raise_for_status()
            out["first_photo_s"] = time.monotonic() - t
            out["first_reconstruction_s"] = _reconstruct(http, flight, app, log)
            out["second_reconstruction_s"] = _reconstruct(http, flight, app, log)  # warm: the comparison
            kernels = wait_for(lambda: (k := http.get("/readyz").json()["checks"]["kernels"])["state"] != "warming"
                               and k, 900, "the kernel warm-up", app.proc, log)
            out.setdefault("kernels_warm_s", time.monotonic() - t0)  # an upper bound: checked after the work above
            out["kernels"] = kernels
    return out


def service(tmp: Path, flight: tuple[Path, dict]) -> dict:
    from workers.common.datasets import data_root

    face = next(iter(sorted((data_root() / "faces" / "dev").rglob("*.jpg"))), None)
    photo = face.read_bytes() if face is not None else _synthetic_photo()
    data_dir, user = tmp / "service-data", tmp / "user-cache"
    install_s, demo_s = install_warmup(data_dir, user)
    return {"install_warmup_s": install_s, "install_demo_recording_s": demo_s,
            "first_start": service_start(data_dir, user, tmp / "first.log", photo, flight),
            "restart": service_start(data_dir, user, tmp / "restart.log", photo, flight),
            "fresh_data_dir": service_start(tmp / "other-data", user, tmp / "fresh.log", photo, flight),
            "pip_install": pip_install_start(tmp, photo, flight),
            "empty_cache": service_start(tmp / "bare-data", tmp / "bare-user-cache", tmp / "bare.log", photo, flight)}


def pip_install_start(tmp: Path, photo: bytes, flight: tuple[Path, dict]) -> dict:
    """``make wheel``'s wheel (built here), ``pip install`` into a new virtual environment, then the first start of
    ``sweepcast serve`` from it with a new data folder and an empty user cache; with the build's and the install's
    seconds."""
    t = time.monotonic()
    subprocess.run(["bash", str(ROOT / "packaging" / "build-wheel.sh"), str(tmp / "dist")], check=True,
                   stdout=subprocess.DEVNULL, env={**os.environ, "PYTHON": sys.executable})
    build_s = time.monotonic() - t
    wheel = next((tmp / "dist").glob("sweepcast-*.whl"))
    venv = tmp / "pip-venv"
    t = time.monotonic()
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet", str(wheel)], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    install_s = time.monotonic() - t
    (tmp / "pip-home").mkdir()
    out = service_start(tmp / "pip-home" / "data", tmp / "pip-home" / "user-cache", tmp / "pip.log", photo, flight,
                        installed=venv)
    return {**out, "wheel_build_s": build_s, "wheel_mb": wheel.stat().st_size / 1e6, "pip_install_s": install_s}


def image_path() -> dict | None:
    """The Docker image's figures from the last ``docker/verify-stack.sh`` run (``benchmarks/docker_stack.py``), in
    the same shape as a service start where it measured the same thing; None when it never ran here."""
    path = ROOT / "benchmarks" / "results" / "docker.json"
    if not path.exists():
        return None
    d = json.loads(path.read_text())
    jobs, viewer = d["jobs"], d["viewer"]
    alone = d.get("standalone")  # the image as one container, timed as a service start (docker_stack.standalone)
    return {**({"standalone": alone} if alone else {}), "ready_s": d["up_to_ready_s"], "first_photo_s": jobs["photo_batch"]["seconds"],
            "photos": jobs["photo_batch"]["photos"], "first_reconstruction_s": jobs["reconstruction"]["seconds"],
            "first_frame_s": viewer["first_frame_s"], "date": d["meta"]["date"], "commit": d["image"]["commit"][:7],
            "image_build_s": d["image"]["seconds"], "second_reconstruction_s": d["jobs"].get("second_reconstruction", {}).get("seconds")}


def _synthetic_photo() -> bytes:
    import cv2
    import numpy as np

    return cv2.imencode(".jpg", np.random.default_rng(0).integers(0, 256, (480, 640, 3), np.uint8))[1].tobytes()


PATHS = [("first_start", "`make serve`: first start"), ("restart", "`make serve`: restart"),
         ("fresh_data_dir", "a fresh data folder"), ("pip_install", "`pip install` of the wheel, first start"),
         ("empty_cache", "empty caches, no kernels shipped")]


def _cell(value: float | None, digits: int = 1) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def markdown(r: dict) -> str:
    rows = [[name, f"{v['compile_s']:.1f}", f"{v['cached_s']:.2f}"] for name, v in r["kernels"].items()]
    load = r["load_average_before"]
    parts = [load_note(load), "",
             "Kernels, each engine's warm-up (`workers.warmup`) in a fresh process: with an empty cache, and with "
             "the cache the first process wrote.", "", md_table(["engine", "compile (s)", "from cache (s)"], rows), ""]
    rows = [[name, f"{v['cold_s']:.2f}", f"{v['warm_start_s']:.2f}", f"{v['steady_s']:.2f}"]
            for name, v in r["first_calls"].items()]
    parts += ["First calls in a fresh worker process (synthetic BA 6 cameras x 250 points; drone pipeline on a "
              "36-frame 320x240 generated flight): empty cache, warm cache, and the second call.", "",
              md_table(["work", "cold (s)", "warm start (s)", "steady (s)"], rows), ""]
    sv, image = r["service"], r.get("image")
    for start in sv.values():
        if isinstance(start, dict):
            start["reconstruction_x"] = start["first_reconstruction_s"] / start["second_reconstruction_s"]
    alone = (image or {}).get("standalone")
    for figures in (image, alone):
        if figures and figures.get("second_reconstruction_s"):
            figures["reconstruction_x"] = figures["first_reconstruction_s"] / figures["second_reconstruction_s"]
    keys = [("answering_s", "`/healthz` 200 after start (the API answers)", None),
            ("ready_s", "`/readyz` 200 after start", f"<= {GOALS['ready_s']:.0f}"),
            ("kernels_warm_s", "kernel warm-up done after start (at ready: none needed; else seen after the work below)",
             None),
            ("demo_ready_s", "demo recording ready after start", None),
            ("first_frame_after_ready_s", "first viewer frame after ready (includes waiting for the demo recording)",
             f"<= {GOALS['first_frame_after_ready_s']:.0f}"),
            ("first_frame_s", "first viewer frame after the recording is ready", None),
            ("first_photo_s", "then: the first photo's orientation", None),
            ("first_reconstruction_s", "then: the first reconstruction (36 frames)", None),
            ("second_reconstruction_s", "then: the same reconstruction again (warm)", None),
            ("reconstruction_x", "first / warm reconstruction", f"<= {GOALS['first_reconstruction_x']:.0f}")]
    images = [*([("the Docker image alone (`podman run`, standalone)", alone)] if alone else []),
              *([("the compose stack (verify-stack.sh)", image)] if image else [])]
    header = ["", *(label for _, label in PATHS), *(label for label, _ in images), "goal"]
    table = []
    for key, label, goal in keys:
        digits = 2 if key == "reconstruction_x" else 1
        row = [label, *(_cell(sv[name].get(key), digits) for name, _ in PATHS)]
        row += [_cell(figures.get(key), digits) for _, figures in images]
        table.append(row + [goal or ""])
    parts += ["`python -m app serve` on each install path, each with a user cache of its own (`XDG_CACHE_HOME`: the "
              "kernels and the demo recording): the first `make serve` fills it before starting the service "
              f"(`sweepcast warmup`, kernels in one process per core, then the demo recording: "
              f"**{sv['install_warmup_s']:.1f} s**, of it {sv['install_demo_recording_s']:.1f} s the recording) and "
              "starts on a fresh data folder (no demo rig), then restarts on it; a fresh data folder on the same "
              "machine (another `--data-dir`, the same user cache); the first `sweepcast serve` after `pip install` "
              "of the wheel `make wheel` builds (kernels compiled for x86-64-v3 and the demo recording inside: "
              f"built in {sv['pip_install']['wheel_build_s']:.0f} s, {sv['pip_install']['wheel_mb']:.1f} MB, "
              f"installed into a new virtual environment in {sv['pip_install']['pip_install_s']:.0f} s from pip's "
              "cache; run from a folder outside the checkout, new data folder, empty user cache); and this checkout "
              "with a new folder and an empty user cache (what a CPU without x86-64-v3, or a Python or numba other "
              "than the wheel's, gets: kernels compile in the background while requests come, the demo job renders "
              "its recording); seconds.", ""]
    if image:
        parts += [f"The Docker image's columns come from the last `docker/verify-stack.sh` run ({image['date']}, image "
                  f"built from {image['commit']} in {image['image_build_s']} s, empty volumes; "
                  "`benchmarks/results/docker.json`): "
                  + ("the image alone first (`podman run ... standalone` on a new volume, nothing else running: local "
                     "Ray, SQLite; timed as a service start here"
                     + (f"; ready is the median of {len(alone['ready_samples_s'])} starts, "
                        + ", ".join(f"{v:.1f}" for v in alone["ready_samples_s"]) + " s"
                        if alone.get("ready_samples_s") else "") + "), then " if alone else "")
                  + "the compose stack, where the steps come in another order: ready is `up` to `/readyz` on both API "
                  "replicas (eight containers booting at once on this machine, which podman-compose starts one after "
                  f"another), the first photo is a batch of {image['photos']} photos, and the viewer's first frame "
                  "comes after the jobs.", ""]
    parts += [md_table(header, table), ""]
    first, again = sv["first_start"], sv["restart"]
    slow = [label for name, label in PATHS
            if sv[name]["first_frame_after_ready_s"] > GOALS["first_frame_after_ready_s"]]
    if slow:
        parts += [f"First viewer frame over the goal ({', '.join(slow)}): it includes the wait for the demo recording "
                  "(10 cameras x 12 frames of the studio: the service publishes the one kept in the user cache before "
                  "Ray is up; a job on Ray renders it when none was kept) and, with empty caches, the renderer's "
                  "kernels compiling in the session actor. Then the frame: the viewer's session actor, a new Ray worker "
                  "process that imports the renderer, loads its kernels from the cache (numba sets up its CPU target "
                  "on the first) and renders.", ""]
    if max(sv[name]["ready_s"] for name, _ in PATHS) > GOALS["ready_s"]:
        ray = r["ray_start"]
        parts += [f"Readiness waits for Ray: the API answers {again['answering_s']:.1f} s after a restart, and "
                  f"a local Ray started alone in a fresh process (`ray.init` as the service calls it, after "
                  f"{ray['import_s']:.1f} s of importing ray) takes **{ray['init_s']:.1f} s** on this machine: its "
                  "GCS, raylet and their agents are processes that start and register one after the other. The "
                  "service starts Ray first and imports itself meanwhile (`raycluster.start_connecting`). Limit: "
                  f"CPU. By `/readyz` 200 the service's processes (the API's imports, Ray's processes, most of them "
                  f"Python importing ray, and the kernel warm-up where the cache was not stamped current) had used "
                  f"{again['cpu_at_ready_s']:.1f} CPU-seconds on a restart ({first['cpu_at_ready_s']:.1f} on the first "
                  f"start): on {os.cpu_count()} cores no less than "
                  f"{again['cpu_at_ready_s'] / (os.cpu_count() or 1):.1f} s.", ""]
    return "\n".join(parts)


def main() -> int:
    ap = argparse.ArgumentParser(prog=prog(), description=__doc__.splitlines()[0])
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
    results["image"] = image_path()
    if "service" in results:
        publish("coldstart", results, markdown(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
