"""What the kernels lose when compiled for a portable CPU baseline (the Docker image's x86-64-v3) instead of this CPU.

The image compiles every kernel once at build for x86-64-v3 (``sweepcast warmup --target x86-64-v3``), so that
any x86-64 server since 2013-2017 loads them instead of compiling; numba otherwise compiles for the CPU it runs on
(here its name and features, AVX-512 included where the CPU has it). Each workload below runs in a fresh process
per target, the same inputs, after one call that loads (or compiles) its kernels; the two targets' processes
alternate for ``--rounds`` rounds, and the figure is the fastest timed call of all rounds (the least disturbed by
other work on the machine), the ratio baseline / this CPU in the same run.

Workloads (the service's hot paths): a viewer frame of the sweep renderer (10 cameras 640x480, a 320x240 view
with 48 planes, and 640x480 with 64 planes), a bundle adjustment (6 cameras x 250 points, 50 iterations), the
dense pass's depth maps (four 160x120 views, 64 planes) and a depth post-filter (wmf_dilation, 512x384 x2).

Run: ``python -m benchmarks.kernel_target`` from the repository root (kernels compiled once into the checkout's
cache, ``sweepcast-data/cache/numba``, for each target: about five minutes the first time on 2 cores).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from benchmarks._report import md_table, prog, publish
from benchmarks._timing import load_note
from workers.portable_cache import host_cpu, host_supports, target_env

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "sweepcast-data" / "cache" / "numba"
BASELINE = "x86-64-v3"

_WORKLOADS = r"""
import json, sys, time
import numpy as np
sys.path.insert(0, {root!r})

def sweep(size, planes):
    from workers.sweep.renderer import RenderOptions, SweepRenderer
    from workers.sweep.rig import Rig
    from workers.synth import default_arc_rig, default_scene, render_views
    cams = default_arc_rig(10, width=640, height=480)
    views = render_views(default_scene(), cams, with_background=True)
    renderer = SweepRenderer(Rig(tuple(cams)), [v.image for v in views], backgrounds=[v.background for v in views])
    virtual = default_arc_rig(9, width=size[0], height=size[1])[4]
    return lambda: renderer.render(virtual, RenderOptions(planes=planes))

def bundle_adjustment():
    from harness.bundle_problem import K, line_of_cameras
    from workers.drone import bundle
    from workers.drone.camera_models import PinholeModel, pose_params
    R, t, X, ci, pj, obs = line_of_cameras()
    params = pose_params(R, t) + np.r_[np.zeros(6), np.full(30, 0.01)].reshape(6, 6)
    fixed = np.zeros((6, 6), bool); fixed[0] = True; fixed[1, 3:] = True
    return lambda: bundle.solve(PinholeModel(K, 6), params, X + 0.05, ci, pj, obs, fixed,
                                bundle.BAOptions(max_iterations=50))

def dense_maps():
    from workers.drone import dense
    from workers.drone.params import ReconstructionParams
    rng = np.random.default_rng(0)
    K = np.array([[130.0, 0, 79.5], [0, 130.0, 59.5], [0, 0, 1]])
    wall = rng.integers(0, 256, (120, 160, 3), np.uint8)
    views = [dense.View.from_pose(f"v{{i}}", np.roll(wall, -2 * i, axis=1), K, np.eye(3),
                                  np.array([-0.03 * i, 0, 0]))
             for i in range(4)]
    points = np.column_stack([rng.uniform(-0.5, 0.5, 200), rng.uniform(-0.4, 0.4, 200), np.full(200, 2.0)])
    params = ReconstructionParams(fx=130.0, fy=130.0, cx=79.5, cy=59.5, dense=True, dense_planes=64)
    return lambda: dense.densify_views(views, points, [np.arange(200)] * 4, params)

def depth_filter():
    from workers.common.images import encode_png
    from workers.depth import io
    from workers.depth.encoded import filter_depth_bytes
    rng = np.random.default_rng(0)
    depth = np.kron(rng.integers(1, 255, (24, 32), np.uint8), np.ones((8, 8), np.uint8))
    texture = encode_png(rng.integers(0, 256, (384, 512, 3), np.uint8))
    blob = io.encode_depth(depth[:192, :256])
    return lambda: filter_depth_bytes(blob, {{"method": "wmf_dilation", "scale": 2}}, texture)

WORKLOADS = {{"sweep 320x240, 48 planes": lambda: sweep((320, 240), 48),
             "sweep 640x480, 64 planes": lambda: sweep((640, 480), 64),
             "bundle adjustment 6x250, 50 it.": bundle_adjustment, "dense depth maps 4x160x120": dense_maps,
             "depth filter wmf_dilation x2": depth_filter}}
out = {{}}
for name, make in WORKLOADS.items():
    run = make()
    run()  # loads (or compiles) its kernels
    times = []
    for _ in range({repeats}):
        t0 = time.perf_counter(); run(); times.append(time.perf_counter() - t0)
    out[name] = min(times) * 1000
print(json.dumps(out))
"""


def run_target(env_extra: dict[str, str], repeats: int) -> dict[str, float]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CPU_")}
    env.update(NUMBA_CACHE_DIR=str(CACHE), **env_extra)
    done = subprocess.run([sys.executable, "-c", _WORKLOADS.format(root=str(ROOT), repeats=repeats)], cwd=ROOT,
                          env=env, check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def markdown(r: dict) -> str:
    rows = [[name, f"{host:.1f}", f"{r['baseline_ms'][name]:.1f}", f"{r['baseline_ms'][name] / host:.2f}"]
            for name, host in r["host_ms"].items()]
    load = r["load_average_before"]
    return "\n".join([
        load_note(load) + (" At such a load the ratios are the figures to read" + (", and only roughly: more work than "
           "cores" if load > (os.cpu_count() or 1) else "") + "." if load > 0.5 else ""), "",
        f"This CPU: `{r['host_cpu']}`; the baseline: `{BASELINE}` (the Docker image's kernels). Fastest ms per call "
        f"of {r['repeats']} after one that loads the kernels, in each of {r['rounds']} rounds; each target in its own "
        "fresh process, the targets alternating.", "",
        md_table(["workload", f"this CPU ({r['host_cpu']}) ms", f"{BASELINE} ms", "baseline / this CPU"], rows), ""])


def main() -> int:
    ap = argparse.ArgumentParser(prog=prog(), description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    missing = host_supports(BASELINE)
    if missing:
        raise SystemExit(f"this CPU lacks {', '.join(missing)}: it cannot run {BASELINE} code")
    load = os.getloadavg()[0]
    host: dict[str, float] = {}
    baseline: dict[str, float] = {}
    for _ in range(args.rounds):
        for best, env in ((host, {}), (baseline, target_env(BASELINE))):
            for name, ms in run_target(env, args.repeats).items():
                best[name] = min(ms, best.get(name, ms))
    results = {"host_cpu": host_cpu()[0], "baseline": BASELINE, "repeats": args.repeats, "rounds": args.rounds,
               "host_ms": host,
               "baseline_ms": baseline, "load_average_before": load}
    print(json.dumps(results, indent=1), file=sys.stderr)
    publish("kernel_target", results, markdown(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
