"""Synthetic nadir surveys of any size and how a map of one compares with its truth, for ``benchmarks/drone.py``
(the ``mapping`` and ``scale`` sections).

- :func:`survey` renders (once: the stills are kept in a cache folder keyed by every setting) a lawnmower survey
  over an area, the scene's buildings and trees as dense as over the benchmarks' 160 m square, with the
  renders spread over processes.
- :func:`evaluate` reads a job's ``dsm.tif`` and ``orthophoto.tif`` window by window (a 1,000-still map is ~30 M
  cells) against the scene ray-cast from above on the same cells: the DSM's error in its own cells, the
  orthophoto's PSNR, and the coverage of the union of every photo's *true* footprint (each camera's image border,
  through its lens, cast onto the ground), whether or not the job registered it.
"""
from __future__ import annotations

import hashlib
import json
import math
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from workers.camera import Camera
from workers.drone.surface import Grid
from workers.drone.survey.ground import image_border

EPSG = 32632
ORIGIN = (431000.0, 5205000.0, 400.0)  # UTM 32N near 47 N, 8 E; the scene's z = 0 at 400 m altitude
DIST = (-0.05, 0.01, 0.0, 0.0)
ALTITUDE = 60.0
F35 = 25  # EXIF FocalLengthIn35mmFilm (an integer, as cameras write it): 1.1 % off the true lens
SCENE_SIDE = 160.0
BUILDINGS, TREES = 14, 24
"""The mapping section's scene: this many buildings and trees in a 160 m square (the 80 x 60 m survey's); a larger
area's square reaches 40 m beyond it on every side (the footprints' half width at 60 m is 42 m) at that density."""
WINDOW = 1024


@dataclass
class Survey:
    """A rendered survey: the stills' folder, the true cameras, the scene, the area (m) and the render's seconds
    (0 when the stills came from the cache)."""

    folder: Path
    cameras: list[Camera]
    scene: Any
    area: tuple[float, float]
    render_s: float


def _scene(area: tuple[float, float], seed: int):
    from workers.synth.survey import survey_scene

    side = max(SCENE_SIDE, max(area) + 80.0)
    density = (side / SCENE_SIDE) ** 2
    return survey_scene(seed, extent=side, n_buildings=int(round(BUILDINGS * density)),
                        n_trees=int(round(TREES * density)))


def survey_cameras(area: tuple[float, float], size: tuple[int, int], seed: int = 1) -> list[Camera]:
    """The true cameras of the survey of ``area`` in stills of ``size`` (without rendering it)."""
    from workers.synth.survey import survey_cameras as cameras

    return cameras(area, ALTITUDE, width=size[0], height=size[1], fov_deg=70.0, dist=DIST, jitter_deg=1.0, seed=seed)


def photos_for(area: tuple[float, float], size: tuple[int, int] = (640, 480), seed: int = 1) -> int:
    """How many stills a survey of ``area`` takes (without rendering them)."""
    return len(survey_cameras(area, size, seed))


def _render_part(args: tuple) -> list[np.ndarray]:
    from workers.synth.flight import render_flight

    area, size, seed, supersample, lo, hi = args
    scene = _scene(area, seed)
    cams = survey_cameras(area, size, seed)
    # each still's own noise seed: the same pixels whichever process renders it
    return [render_flight(scene, [cams[i]], noise_sigma=1.0, supersample=supersample, seed=seed * 100_003 + i)[0]
            for i in range(lo, hi)]


def survey(area: tuple[float, float], size: tuple[int, int], cache: Path, seed: int = 1, supersample: int = 3,
           processes: int | None = None) -> Survey:
    """The survey of ``area`` (m, x by y) in stills of ``size`` (w, h): rendered into ``cache`` unless already there
    (a folder named after every setting), the renders spread over ``processes`` (default: every core)."""
    from workers.synth.survey import write_geotagged_stills

    key = json.dumps({"area": area, "size": size, "seed": seed, "supersample": supersample, "dist": DIST,
                      "altitude": ALTITUDE, "f35": F35, "origin": ORIGIN, "version": 2}, sort_keys=True)
    folder = Path(cache) / f"survey-{hashlib.sha256(key.encode()).hexdigest()[:16]}"
    cams = survey_cameras(area, size, seed)
    scene = _scene(area, seed)
    done = folder / "complete.json"
    if done.exists():
        return Survey(folder, cams, scene, area, 0.0)
    t0 = time.perf_counter()
    n = len(cams)
    workers = max(1, processes or os.cpu_count() or 1)
    chunk = max(1, math.ceil(n / (workers * 4)))
    parts = [(area, size, seed, supersample, lo, min(n, lo + chunk)) for lo in range(0, n, chunk)]
    rendered: dict[int, list[np.ndarray]] = {}
    try:
        # spawned, not forked: a fork of a process whose numba kernels already started their threads can abort
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            for k, frames in enumerate(pool.map(_render_part, parts)):
                rendered[k] = frames
    except BrokenProcessPool as exc:  # a render process died (the machine's memory): go on here
        print(f"survey: a render process ended ({exc}); rendering the rest in this process", flush=True)
    frames = [f for k, part in enumerate(parts) for f in (rendered[k] if k in rendered else _render_part(part))]
    write_geotagged_stills(folder, frames, cams, EPSG, ORIGIN, focal_35mm=F35)
    done.write_text(key)
    return Survey(folder, cams, scene, area, time.perf_counter() - t0)


def true_footprints(cams: list[Camera], per_side: int = 16) -> list[np.ndarray]:
    """Each camera's true footprint: its image border, through its lens, cast onto the ground z = 0 (scene frame),
    (K, 2) x, y."""
    out = []
    for cam in cams:
        rays = cam.rays(image_border(cam.width, cam.height, per_side))
        t = -cam.center[2] / rays[:, 2]
        out.append(cam.center[:2] + t[:, None] * rays[:, :2])
    return out


def _psnr(sse: float, n: int) -> float:
    return 10 * math.log10(255.0**2 / max(sse / max(n, 1), 1e-12))


STEREO_VIEWS = 5
"""Cells at least this many true footprints cover: where the dense pass can see the ground (a reference and its
best four neighbours); the rest, the survey's rim, has its heights from sparse points and the fill."""


def evaluate(results: Path, sv: Survey) -> dict[str, Any]:
    """The job's ``dsm.tif`` and ``orthophoto.tif`` in ``results`` against the truth of ``sv`` (module docstring):
    DSM error in its own cells (GSD units: median absolute, median, RMSE, share within 1), orthophoto PSNR over
    its coloured cells (whole, open ground farther than 1 m from any object, objects and their edges, and where at
    least :data:`STEREO_VIEWS` photos saw the ground), coverage of the true footprints' union by DSM heights and by
    orthophoto colours."""
    import rasterio
    from rasterio.windows import Window

    from workers.synth.survey import true_orthophoto

    prints = true_footprints(sv.cameras)
    out: dict[str, Any] = {}
    with rasterio.open(results / "dsm.tif") as src:
        gsd = src.transform.a
        x0, y0 = src.transform.c - ORIGIN[0], src.transform.f - ORIGIN[1]
        errs, stereo_errs, union, covered = [], [], 0, 0
        for r0 in range(0, src.height, WINDOW):
            for c0 in range(0, src.width, WINDOW):
                h, w = min(WINDOW, src.height - r0), min(WINDOW, src.width - c0)
                band = src.read(1, window=Window(c0, r0, w, h), masked=True)
                grid = Grid(x0 + c0 * gsd, y0 - r0 * gsd, gsd, w, h)
                views = _views(grid, prints)
                known = ~np.ma.getmaskarray(band)
                union += int((views > 0).sum())
                covered += int(((views > 0) & known).sum())
                if known.any():
                    _, truth_z = true_orthophoto(sv.scene, grid.x0, grid.y0, gsd, w, h, supersample=1)
                    ok = known & np.isfinite(truth_z)
                    e = (band.data - ORIGIN[2] - truth_z) / gsd
                    errs.append(e[ok])
                    stereo_errs.append(e[ok & (views >= STEREO_VIEWS)])
        e = np.concatenate(errs) if errs else np.zeros(0)
        es = np.concatenate(stereo_errs) if stereo_errs else np.zeros(0)
        out["dsm"] = {"gsd_m": gsd, "cells": int(len(e)), "median_abs_gsd": float(np.median(np.abs(e))),
                      "median_gsd": float(np.median(e)), "rmse_gsd": float(np.sqrt(np.mean(e**2))),
                      "within_1_gsd": float(np.mean(np.abs(e) <= 1.0)), "coverage": covered / max(union, 1),
                      "stereo_share": len(es) / max(len(e), 1),
                      "stereo_median_abs_gsd": float(np.median(np.abs(es))) if len(es) else None}
    with rasterio.open(results / "orthophoto.tif") as src:
        gsd = src.transform.a
        x0, y0 = src.transform.c - ORIGIN[0], src.transform.f - ORIGIN[1]
        sse = {"all": 0.0, "open_ground": 0.0, "objects_and_edges": 0.0, "stereo": 0.0}
        count = dict.fromkeys(sse, 0)
        union = covered = 0
        k = 2 * int(round(1.0 / gsd)) + 1
        for r0 in range(0, src.height, WINDOW):
            for c0 in range(0, src.width, WINDOW):
                h, w = min(WINDOW, src.height - r0), min(WINDOW, src.width - c0)
                rgba = np.moveaxis(src.read(window=Window(c0, r0, w, h)), 0, 2)
                grid = Grid(x0 + c0 * gsd, y0 - r0 * gsd, gsd, w, h)
                views = _views(grid, prints)
                mask = views > 0
                seen = rgba[..., 3] > 0
                union += int(mask.sum())
                covered += int((mask & seen).sum())
                if not seen.any():
                    continue
                truth_bgr, truth_z = true_orthophoto(sv.scene, grid.x0, grid.y0, gsd, w, h, supersample=3)
                diff = (rgba[..., :3].astype(np.float64) - truth_bgr[..., ::-1]) ** 2
                flat = np.isfinite(truth_z) & (np.abs(truth_z) < 1e-6)
                open_ground = cv2.erode(flat.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)
                for name, m in (("all", seen), ("open_ground", seen & open_ground),
                                ("objects_and_edges", seen & ~open_ground), ("stereo", seen & (views >= STEREO_VIEWS))):
                    sse[name] += float(diff[m].sum())
                    count[name] += int(m.sum()) * 3
        out["orthophoto"] = {"gsd_m": gsd, "size": [src.width, src.height], "coverage": covered / max(union, 1),
                             **{f"psnr_{k}_db": _psnr(sse[k], count[k]) for k in sse},
                             "objects_and_edges_share": count["objects_and_edges"] / max(count["all"], 1),
                             "stereo_share": count["stereo"] / max(count["all"], 1)}
    out["true_footprint_union_m2"] = union * gsd * gsd
    return out


def _views(grid: Grid, prints: list[np.ndarray]) -> np.ndarray:
    """(H, W) how many true footprints cover each cell of ``grid`` (scene frame)."""
    from workers.drone.survey.ground import footprint_mask, overlapping

    box = (grid.x0, grid.x0 + grid.width * grid.gsd, grid.y0 - grid.height * grid.gsd, grid.y0)
    count = np.zeros((grid.height, grid.width), np.int32)
    for i in overlapping(dict(enumerate(prints)), box):
        count += footprint_mask(grid, [prints[i]])
    return count
