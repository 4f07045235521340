"""Compile every engine's numba kernels once per machine, ahead of the first request.

The kernels are ``@njit(cache=True)``: the first process that calls one compiles it (seconds to tens
of seconds each; benchmarks/RESULTS.md, section coldstart) and writes the machine code to
numba's cache; every later process loads it in milliseconds. numba keys each cached entry by the
SHA-256 of the function's source file, the argument types and the CPU target (name and features), so one
cache directory serves every CPU kind that uses it and a changed source recompiles; and our kernels are filed
by their path inside the project (:mod:`workers.portable_cache`), so a cache compiled ahead serves any install
of the same sources. ``--target x86-64-v3`` compiles for a portable CPU baseline instead of this CPU (an image
build does, for the machines that will run the image).

:func:`warm` runs each engine's real entry points on tiny generated inputs, so that exactly the
specialisations a request uses are compiled (the same dtypes, dimensions and array layouts), and
returns how long each engine took. ``sweepcast serve`` runs it in a background process at start-up
(``SWEEPCAST_WARM_KERNELS``); ``sweepcast warmup`` runs it by hand (e.g. when building an image).
Where the cache lives: ``NUMBA_CACHE_DIR`` when set, which the service sets from
``SWEEPCAST_NUMBA_CACHE_DIR`` (default ``~/.cache/sweepcast/kernels``) for itself and its workers.
"""
from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np

from workers.portable_cache import STAMP_NAME, TARGETS, configured_target, host_supports, target_env


def _sweep() -> None:
    """The renderer in every configuration a viewer, a batch render or a live rig can ask for (the
    compiled variants differ by visual hull, cost and aggregation); the demo recording's ray caster."""
    from workers.sweep.renderer import RenderOptions, SweepRenderer
    from workers.sweep.rig import Rig
    from workers.synth import default_arc_rig, default_scene, render_views

    cams = default_arc_rig(4, width=48, height=36)
    views = render_views(default_scene(), cams, with_background=True)
    images = [v.image for v in views]
    virtual = cams[1]
    with_hull = SweepRenderer(Rig(tuple(cams)), images, backgrounds=[v.background for v in views])
    without_hull = SweepRenderer(Rig(tuple(cams)), images)
    live = SweepRenderer(Rig(tuple(cams)), images, silhouettes=[np.ones((36, 48), bool)] * len(cams))
    for renderer in (with_hull, without_hull, live):
        for aggregation in ("none", "window", "sgm"):
            for coarse in (False, True):
                renderer.render(virtual, RenderOptions(planes=8, aggregation=aggregation, coarse_to_fine=coarse))
        renderer.render(virtual, RenderOptions(planes=8, consistency="truncated"))
    for method in RenderOptions.model_fields["method"].annotation.__args__:
        with_hull.render(virtual, RenderOptions(planes=8, method=method))
    for visibility in (True, False):
        with_hull.render(virtual, RenderOptions(planes=8, visibility=visibility))
    for coarse in (False, True):  # the occlusion fill's cross-view check and background fill
        with_hull.render(virtual, RenderOptions(planes=8, coarse_to_fine=coarse, occlusions="fill"))
    # a stream's next frame set: which camera pixels changed, and the previous depth kept where none did
    first = with_hull.render(virtual, RenderOptions(planes=8, coarse_to_fine=True, aggregation="sgm"))
    with_hull.set_frames(images)
    with_hull.render(virtual, RenderOptions(planes=8, coarse_to_fine=True, aggregation="sgm"), previous=first)


def _demo() -> None:
    """The first-run demo recording's renderer (the studio's ray caster, textures and soft shadows)."""
    import tempfile
    from pathlib import Path

    from workers.streaming.demo import build_demo_recording, demo_rig

    with tempfile.TemporaryDirectory(prefix="sweepcast-warmup-") as tmp:
        build_demo_recording(demo_rig(2, (32, 24)), Path(tmp) / "demo.zip", frames=2, fps=1.0)


def _bundle() -> None:
    """The bundle adjuster with every camera model (the drone pipeline's pinhole, the self-calibrating radial
    camera with its priors and information, BAL's camera)."""
    from workers.drone import bundle
    from workers.drone.camera_models import BALModel, PinholeModel, RadialModel, pose_params

    rng = np.random.default_rng(0)
    n_cams, n_pts = 3, 30
    X = np.column_stack([rng.uniform(-1, 1, n_pts), rng.uniform(-1, 1, n_pts), rng.uniform(4, 6, n_pts)])
    R = np.repeat(np.eye(3)[None], n_cams, axis=0)
    t = np.column_stack([-np.linspace(0, 1, n_cams), np.zeros(n_cams), np.zeros(n_cams)])
    ci = np.repeat(np.arange(n_cams), n_pts)
    pj = np.tile(np.arange(n_pts), n_cams)
    P = np.einsum("nij,nj->ni", R[ci], X[pj]) + t[ci]
    K = np.array([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]])
    obs = P[:, :2] / P[:, 2:] @ K[:2, :2].T + K[:2, 2]
    params = pose_params(R, t)
    fixed = np.zeros_like(params, bool)
    fixed[0] = True
    for loss in ("trivial", "huber", "cauchy"):
        bundle.solve(PinholeModel(K, n_cams), params, X, ci, pj, obs, fixed,
                     bundle.BAOptions(max_iterations=2, loss=loss))
    radial = RadialModel(K[:2, 2])
    shared = np.array([300.0, 0.0, 0.0])
    prior = bundle.SharedPrior(shared, np.array([10.0, 0.25, 0.25]))
    centres = bundle.CentrePrior(-np.einsum("nji,nj->ni", R, t), np.ones(n_cams))
    bundle.solve(radial, params, X, ci, pj, obs, fixed, bundle.BAOptions(max_iterations=2, loss="cauchy"),
                 shared=shared, shared_prior=prior, centre_prior=centres)
    bundle.shared_information(radial, params, X, shared, ci, pj, obs, fixed)
    bal = np.column_stack([params, np.full(n_cams, 300.0), np.zeros((n_cams, 2))])
    fixed = np.zeros_like(bal, bool)
    fixed[0] = True
    bundle.solve(BALModel(), bal, X, ci, pj, obs - K[:2, 2], fixed, bundle.BAOptions(max_iterations=2))


def _dense() -> None:
    """The dense pass (ZNCC sweep, coarse-to-fine and SGM, fusion) on four tiny views of a textured wall, and
    the orthophoto's visibility kernels on the same views."""
    from workers.drone import dense
    from workers.drone.orthophoto import orthophoto
    from workers.drone.params import ReconstructionParams
    from workers.drone.surface import Grid

    rng = np.random.default_rng(0)
    K = np.array([[40.0, 0, 23.5], [0, 40.0, 17.5], [0, 0, 1]])
    wall = rng.integers(0, 256, (36, 48, 3), np.uint8)
    views = [dense.View.from_pose(f"v{i}", np.roll(wall, -2 * i, axis=1), K, np.eye(3), np.array([-0.1 * i, 0, 0]))
             for i in range(4)]
    points = np.column_stack([rng.uniform(-0.5, 0.5, 50), rng.uniform(-0.4, 0.4, 50), np.full(50, 2.0)])
    seen = [np.arange(50)] * 4
    for aggregation, coarse in (("window", True), ("window", False), ("sgm", False)):
        params = ReconstructionParams(fx=40.0, fy=40.0, cx=23.5, cy=17.5, dense=True, dense_planes=16,
                                      dense_aggregation=aggregation, dense_coarse_to_fine=coarse)
        dense.densify_views(views, points, seen, params)
    down = [dense.View.from_pose(v.camera.name, v.image, K, np.diag([1.0, -1.0, -1.0]), np.array([0.1 * i, 0.0, 2.0]))
            for i, v in enumerate(views)]
    orthophoto(np.zeros((20, 30), np.float32), Grid(-1.0, 0.7, 0.05, 30, 20), down, dist=np.array([-0.05, 0, 0, 0]))


def _depth() -> None:
    """Every depth post-filter at 8 and 16 bits, and view synthesis for both geometries."""
    from workers.common.images import encode_png
    from workers.depth import io
    from workers.depth.methods import METHODS, GUIDED_METHODS
    from workers.depth.encoded import filter_depth_bytes, synthesize_bytes

    rng = np.random.default_rng(0)
    texture = encode_png(rng.integers(0, 256, (24, 32, 3), np.uint8))
    for depth in (rng.integers(1, 255, (12, 16), np.uint8), rng.integers(1, 65535, (12, 16), np.uint16)):
        blob = io.encode_depth(depth)
        for method in METHODS:
            guide = texture if method in GUIDED_METHODS else None
            filter_depth_bytes(blob, {"method": method, "scale": 2}, guide)
    levels = encode_png(rng.integers(1, 255, (24, 32), np.uint8))
    views = [(texture, levels), (texture, levels)]
    common = {"z_near": 1.0, "z_far": 10.0}
    synthesize_bytes(views, {**common, "focal_px": 40.0, "positions": [0.0, 0.2], "target_position": 0.1})
    K = [[40.0, 0, 15.5], [0, 40.0, 11.5], [0, 0, 1]]
    synthesize_bytes(views, {**common, "geometry": "general", "cameras": [{"K": K, "t": [0.0, 0, 0]},
                                                                          {"K": K, "t": [-0.2, 0, 0]}],
                             "target_camera": {"K": K, "t": [-0.1, 0, 0]}})


def _faces() -> None:
    """The face preview's rasteriser (the face jobs' only compiled kernel)."""
    from workers.faces.preview import preview_png

    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.2]])
    tris = np.array([[0, 1, 2], [1, 3, 2]])
    preview_png(v, v + 0.1, tris)


ENGINES: dict[str, Callable[[], None]] = {"sweep": _sweep, "demo": _demo, "drone": _bundle, "dense": _dense,
                                          "depth": _depth, "faces": _faces}
"""Engine name -> its warm-up, in the order users meet them (the demo viewer first)."""

COMPILE_SECONDS = {"sweep": 77.0, "demo": 3.5, "drone": 42.0, "dense": 33.0, "depth": 7.4, "faces": 2.0}
"""Each engine's compile time from an empty cache on 2 cores (``benchmarks/coldstart.py``, 2026-11-26):
only for sharing the engines out between processes."""


def shares(engines: list[str], jobs: int) -> list[list[str]]:
    """``engines`` split into at most ``jobs`` non-empty groups of about equal compile time (the longest
    first, each to the least loaded group), every group in :data:`ENGINES` order."""
    groups: list[list[str]] = [[] for _ in range(max(1, min(jobs, len(engines))))]
    load = [0.0] * len(groups)
    for name in sorted(engines, key=lambda e: -COMPILE_SECONDS[e]):
        k = load.index(min(load))
        groups[k].append(name)
        load[k] += COMPILE_SECONDS[name]
    order = list(ENGINES)
    return [sorted(g, key=order.index) for g in groups if g]


_WORKERS = Path(__file__).resolve().parent


def fingerprint(target: tuple[str, str] | None = None) -> str:
    """Hex SHA-256 of what every cached kernel depends on, as numba keys its entries: each engine source file
    (path in the package and SHA-256 of its bytes), numba's and Python's versions, and the CPU target
    (``target`` = (LLVM CPU name, feature string); default: the one numba uses in this process)."""
    from importlib.metadata import version

    name, features = target or configured_target()
    h = hashlib.sha256(f"{version('numba')}|{sys.version}|{name}|{features}".encode())
    for path in sorted(_WORKERS.rglob("*.py")):
        h.update(f"\n{path.relative_to(_WORKERS).as_posix()}|{hashlib.sha256(path.read_bytes()).hexdigest()}".encode())
    return h.hexdigest()


def read_stamp(cache_dir: Path) -> dict | None:
    """The stamp of ``cache_dir`` (:data:`STAMP_NAME`), or None when there is none or it is unreadable."""
    try:
        stamp = json.loads((Path(cache_dir) / STAMP_NAME).read_text())
    except (OSError, ValueError):
        return None
    return stamp if isinstance(stamp, dict) else None


def is_current(cache_dir: Path, target: tuple[str, str] | None = None) -> bool:
    """Whether ``cache_dir`` holds every engine's kernels for this code, numba and CPU target (default: this
    process's; a warm-up of all of them stamped it since nothing changed): then a warm-up would only load them."""
    stamp = read_stamp(cache_dir)
    return stamp is not None and stamp.get("fingerprint") == fingerprint(target)


def _stamp(cache_dir: Path) -> None:
    with contextlib.suppress(OSError):  # without the stamp the next start only warms again
        name, features = configured_target()
        part = Path(cache_dir) / f"{STAMP_NAME}.{os.getpid()}.part"
        part.write_text(json.dumps({"fingerprint": fingerprint(), "cpu_name": name, "cpu_features": features}))
        os.replace(part, Path(cache_dir) / STAMP_NAME)


def warm(engines: list[str] | None = None, log: Callable[[str], None] | None = None) -> dict[str, float]:
    """Compile (or load from numba's cache) the kernels of ``engines`` (default: all, in
    :data:`ENGINES` order); returns seconds per engine. An engine that fails is logged and skipped:
    warming is an optimisation, never a reason to stop."""
    seconds: dict[str, float] = {}
    for name in engines or list(ENGINES):
        t0 = time.perf_counter()
        try:
            ENGINES[name]()
        except Exception as exc:  # noqa: BLE001 - a request will compile what this could not
            if log is not None:
                log(f"warming {name} failed: {type(exc).__name__}: {exc}")
            continue
        seconds[name] = round(time.perf_counter() - t0, 3)
        if log is not None:
            log(f"warmed {name} in {seconds[name]:.1f} s")
    return seconds


def warm_in_processes(engines: list[str], jobs: int, log: Callable[[str], None] | None = None) -> dict[str, float]:
    """:func:`warm` with ``engines`` shared out over ``jobs`` processes at once (numba compiles on one
    core: two processes on two cores take about half the time); seconds per engine."""
    groups = shares(engines, jobs)
    if len(groups) == 1:
        return warm(groups[0], log)
    procs = [subprocess.Popen([sys.executable, "-m", "workers.warmup", "--jobs", "1", *g], stdout=subprocess.PIPE,
                              stdin=subprocess.DEVNULL) for g in groups]
    seconds: dict[str, float] = {}
    for proc in procs:
        out, _ = proc.communicate()
        try:  # a group that failed is only slower later: its kernels compile on first use
            seconds.update(json.loads(out.decode().strip().splitlines()[-1]))
        except (ValueError, IndexError):
            if log is not None:
                log(f"a warm-up process exited with code {proc.returncode}")
    return {name: seconds[name] for name in ENGINES if name in seconds}


def render_demo_recording(cache_dir: Path) -> float:
    """Render the first-run demo recording (the demo rig, the demo job's default length) into ``cache_dir``,
    which a new data folder's demo gets without rendering it (about 20 s of two
    cores); seconds taken (a copy already there: none to speak of)."""
    from workers.streaming.demo import demo_recording, demo_rig
    from workers.streaming.params import DemoParams

    t0 = time.perf_counter()
    p = DemoParams()
    with tempfile.TemporaryDirectory() as tmp:
        demo_recording(demo_rig(), Path(tmp) / "demo.zip", p.frames, p.fps, cache_dir)
    return round(time.perf_counter() - t0, 3)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="sweepcast warmup", description="compile every engine's kernels into "
                                 "numba's cache (NUMBA_CACHE_DIR) ahead of the first request")
    ap.add_argument("engines", nargs="*", metavar="ENGINE", help=f"any of {', '.join(ENGINES)} (default: all)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                    help="processes compiling at once (default: one per core)")
    ap.add_argument("--target", choices=sorted(TARGETS),
                    help="compile for this portable CPU baseline instead of this CPU (a cache for other machines)")
    ap.add_argument("--demo-cache", type=Path, metavar="DIR",
                    help="then render the first-run demo recording into DIR (a new data folder's demo then gets it without rendering it)")
    args = ap.parse_args(argv)
    unknown = sorted(set(args.engines) - set(ENGINES))
    if unknown:
        ap.error(f"unknown engine(s) {', '.join(unknown)}; expected any of {', '.join(ENGINES)}")
    if args.jobs < 1:
        ap.error("--jobs must be at least 1")
    if args.target is not None:
        if "numba" in sys.modules and os.environ.get("NUMBA_CPU_NAME") != args.target:
            ap.error("--target must be set before numba is imported")  # numba reads its CPU target only then
        missing = host_supports(args.target)
        if missing:  # the warm-up runs what it compiles
            ap.error(f"this CPU lacks {', '.join(missing)}: it cannot build kernels for {args.target}")
        os.environ.update(target_env(args.target))  # this process and the compiling ones
    log = lambda m: print(m, file=sys.stderr, flush=True)  # noqa: E731
    seconds = warm_in_processes(args.engines or list(ENGINES), args.jobs, log)
    if set(seconds) == set(ENGINES) and os.environ.get("NUMBA_CACHE_DIR"):  # every engine warmed: stamp the cache
        _stamp(Path(os.environ["NUMBA_CACHE_DIR"]))
    if args.demo_cache is not None:
        seconds["demo_recording"] = render_demo_recording(args.demo_cache)
        log(f"rendered the demo recording into {args.demo_cache} in {seconds['demo_recording']:.1f} s")
    print(json.dumps(seconds))
    return 0


if __name__ == "__main__":
    sys.exit(main())
