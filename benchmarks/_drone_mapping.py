"""The ``mapping`` section of ``benchmarks/drone.py`` (issue 32): a drone flight in, a map out.

1. A synthetic nadir survey (workers.synth.survey): geotagged JPEGs of textured ground with buildings
   and trees through a lens with barrel distortion, no intrinsics given. The job's orthophoto and DSM
   against the true ones rendered straight from above (DSM error in GSD units, orthophoto PSNR on the
   covered cells, coverage of the surveyed area, a seams picture); the self-calibrated lens against the
   true one; camera positions against the true ones; GPS as a bundle-adjustment prior with noisy GPS.
2. The 30 real stills (sfm/drone_fc350): the whole job with no parameters (focal length, ATE against
   GPS, the orthophoto's camera-position error, time per stage, pictures), our reconstruction with the
   given intrinsics, and pycolmap's own self-calibration on the same frames.
"""
from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from benchmarks import _survey_eval as _survey
from benchmarks._timing import load_average
from benchmarks._report import RESULTS_DIR, md_table
from workers.common.datasets import dataset
from workers.drone import reconstruction
from workers.drone.evaluation import trajectory_error
from workers.drone.geometry import camera_centre
from workers.drone.params import ReconstructionParams
from workers.drone.pipeline import run_pipeline, write_outputs

try:
    import pycolmap
except ImportError:  # pragma: no cover - optional
    pycolmap = None

# The synthetic survey's place, lens and flight: the scale section's (benchmarks._survey_eval), one definition.
SYNTH_EPSG, SYNTH_ORIGIN, SYNTH_DIST, SYNTH_F35 = _survey.EPSG, _survey.ORIGIN, _survey.DIST, _survey.F35
ALTITUDE = _survey.ALTITUDE
DSM_GOAL_GSD = 1.0
ORTHO_GOAL_DB = 30.0
FOCAL_GOAL = 0.03
JOB_GOAL_S = 120.0
FC350_FOCAL = (693.3, 702.1)  # EXIF: 35 mm equivalent (diagonal) and focal length on the FC350's 6.17 mm sensor
HELD_FOCALS = (400.0, 500.0, 600.0)
"""Focal lengths (px) the sparse model is also run with, held (pycolmap's self-calibration found ~398)."""
RS_READOUT_S = 0.05
"""A generous rolling-shutter readout for a 2015 drone still camera (s), for the bound in the height-pattern text."""
PRIOR_SIGMAS = (1.0, 0.5, 0.2)
"""GPS prior standard deviations (m per axis) the sparse model is also run with, beside the 2 m one."""


# ---------------------------------------------------------------------------------------------
# 1. Synthetic survey
# ---------------------------------------------------------------------------------------------
def _survey(quick: bool):
    from workers.synth.flight import render_flight
    from workers.synth.survey import survey_cameras, survey_scene

    area, size = ((40.0, 30.0), (480, 360)) if quick else ((80.0, 60.0), (640, 480))
    scene = survey_scene(1, extent=160.0)
    cams = survey_cameras(area, ALTITUDE, width=size[0], height=size[1], fov_deg=70.0, dist=SYNTH_DIST,
                          jitter_deg=1.0, seed=1)
    frames = render_flight(scene, cams, noise_sigma=1.0, supersample=3, seed=1)
    return scene, cams, frames, area


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 10 * np.log10(255.0**2 / max(mse, 1e-12))


def _shifted_psnr(ortho: np.ndarray, truth: np.ndarray, covered: np.ndarray) -> tuple[float, tuple[float, float]]:
    """PSNR after moving the orthophoto by the sub-pixel shift that best aligns it with the truth (phase
    correlation of the grey images): the rendering's quality without its georeferencing error."""
    g1 = cv2.cvtColor(np.where(covered[..., None], ortho, 0).astype(np.uint8), cv2.COLOR_RGB2GRAY).astype(np.float32)
    g2 = cv2.cvtColor(np.where(covered[..., None], truth, 0).astype(np.uint8), cv2.COLOR_RGB2GRAY).astype(np.float32)
    win = cv2.createHanningWindow(g1.shape[::-1], cv2.CV_32F)
    (dx, dy), _ = cv2.phaseCorrelate(g1, g2, win)
    M = np.float32([[1, 0, dx], [0, 1, dy]])
    moved = cv2.warpAffine(ortho, M, ortho.shape[1::-1], flags=cv2.INTER_LINEAR)
    still = cv2.warpAffine(covered.astype(np.uint8), M, ortho.shape[1::-1], flags=cv2.INTER_NEAREST).astype(bool)
    both = covered & still
    both = cv2.erode(both.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    return _psnr(moved[both], truth[both]), (float(dx), float(dy))


def _seams_picture(ortho: np.ndarray, truth: np.ndarray, source: np.ndarray, err_gsd: np.ndarray,
                   path: Path) -> None:
    """Truth | orthophoto with the seams between frames in red | DSM error map (blue -2, red +2 GSD)."""
    rgb = ortho[..., :3].copy()
    edges = np.zeros(source.shape, bool)
    edges[:, 1:] |= source[:, 1:] != source[:, :-1]
    edges[1:, :] |= source[1:, :] != source[:-1, :]
    edges = cv2.dilate(edges.astype(np.uint8), np.ones((2, 2), np.uint8)).astype(bool) & (source >= 0)
    rgb[edges] = (255, 0, 0)
    level = np.clip((np.nan_to_num(err_gsd) + 2) / 4 * 255, 0, 255).astype(np.uint8)
    err_rgb = cv2.applyColorMap(level, cv2.COLORMAP_COOL)[..., ::-1]
    err_rgb[~np.isfinite(err_gsd)] = 255
    panel = np.hstack([truth, np.full((truth.shape[0], 8, 3), 255, np.uint8), rgb,
                       np.full((truth.shape[0], 8, 3), 255, np.uint8), err_rgb])
    scale = min(1.0, 2400 / panel.shape[1])
    panel = cv2.resize(panel, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    cv2.imwrite(str(path), panel[..., ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 9])


def _camera_errors(model, cams, offset: np.ndarray) -> dict[str, float]:
    """Absolute error of the georeferenced camera centres against the true ones (no fit) and ATE after a
    similarity, metres."""
    by_name = {c.name + ".jpg": c for c in cams}
    reg = [f for f in np.flatnonzero(model.registered) if model.frame_name[f] in by_name]
    est = np.stack([camera_centre(model.R[f], model.t[f]) for f in reg]) + offset
    true = np.stack([by_name[model.frame_name[f]].center for f in reg])
    d = np.linalg.norm(est - true, axis=1)
    return {"absolute_rmse_m": float(np.sqrt(np.mean(d**2))), "absolute_max_m": float(d.max()),
            "ate_after_similarity_m": trajectory_error(est, true).ate_rmse, "cameras": len(reg)}


def synthetic(quick: bool) -> tuple[dict[str, Any], str]:
    from workers.synth.survey import true_orthophoto, write_geotagged_stills

    t0 = time.perf_counter()
    scene, cams, frames, area = _survey(quick)
    render_s = time.perf_counter() - t0
    w, h = cams[0].width, cams[0].height
    true_f = float(cams[0].K[0, 0])
    work = Path(tempfile.mkdtemp(prefix="mapping_synth_"))
    out: dict[str, Any] = {"images": len(cams), "size": [w, h], "altitude_m": ALTITUDE, "area_m": list(area),
                           "true_focal_px": true_f, "true_distortion": list(SYNTH_DIST[:2]),
                           "exif_focal_35mm": SYNTH_F35, "render_s": round(render_s, 1)}
    try:
        folder = work / "stills"
        write_geotagged_stills(folder, frames, cams, SYNTH_EPSG, SYNTH_ORIGIN, focal_35mm=SYNTH_F35)
        load0 = load_average(2)
        t1 = time.perf_counter()
        res = run_pipeline(folder, ReconstructionParams())
        job_s = time.perf_counter() - t1
        model, ref, maps = res.model, res.georef, res.maps
        offset = ref.origin - np.asarray(SYNTH_ORIGIN)  # world (local UTM) + offset = scene frame
        grid = maps.ground.ortho
        truth_bgr, truth_z = true_orthophoto(scene, grid.x0 + offset[0], grid.y0 + offset[1], grid.gsd, grid.width,
                                             grid.height, supersample=3)
        truth = truth_bgr[..., ::-1]
        f = maps.ground.factor  # the DSM's cells cover f x f of the orthophoto's (1 at these stills' own size)
        dsm = np.repeat(np.repeat(maps.dsm(), f, axis=0), f, axis=1) + offset[2]
        known = np.isfinite(dsm) & np.isfinite(truth_z)
        err = np.full(dsm.shape, np.nan)
        err[known] = (dsm[known] - truth_z[known]) / grid.gsd
        e = err[known]
        ortho = maps.orthophoto()
        covered = ortho[..., 3] > 0
        psnr = _psnr(ortho[..., :3][covered], truth[covered])
        # Ground farther than 1 m from any building or tree, and the rest (objects and their edges).
        flat = np.isfinite(truth_z) & (np.abs(truth_z) < 1e-6)
        k = 2 * int(round(1.0 / grid.gsd)) + 1
        open_ground = cv2.erode(flat.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)
        regions = {"open_ground": covered & open_ground, "objects_and_edges": covered & ~open_ground}
        psnr_aligned, shift = _shifted_psnr(ortho[..., :3], truth, covered)
        stereo = _stereo_cells(res.dense.cloud().points, grid, f)
        by_stereo = {"measured": stereo, "filled": ~stereo}
        xs, ys = grid.centres()
        inside = ((np.abs(xs + offset[0])[None, :] <= area[0] / 2) & (np.abs(ys + offset[1])[:, None] <= area[1] / 2))
        lens = model.report["intrinsics"]
        picture = RESULTS_DIR / "mapping_synthetic_seams.png"
        _seams_picture(ortho, truth, maps.sources(), err, picture)
        out.update({
            "job_s": round(job_s, 1), "load_average": [load0, load_average(2)],
            "timings_s": model.report["timings_s"], "gsd_m": grid.gsd, "grid": [grid.width, grid.height],
            "dsm_error_gsd": {"rmse": float(np.sqrt(np.mean(e**2))), "median_abs": float(np.median(np.abs(e))),
                              "median": float(np.median(e)), "p90_abs": float(np.percentile(np.abs(e), 90)),
                              "within_1": float(np.mean(np.abs(e) <= 1.0)), "cells": int(len(e))},
            "orthophoto_psnr_db": psnr, "orthophoto_psnr_aligned_db": psnr_aligned,
            "orthophoto_psnr_by_region_db": {k: _psnr(ortho[..., :3][m], truth[m]) for k, m in regions.items()},
            "orthophoto_region_share": {k: float(m.sum() / covered.sum()) for k, m in regions.items()},
            "orthophoto_shift_to_truth_px": shift,
            "by_stereo": {k: {"share_of_covered": float((m & covered).sum() / covered.sum()),
                              "dsm_median_abs_gsd": float(np.median(np.abs(err[m & known]))) if (m & known).any() else None,
                              "orthophoto_psnr_db": _psnr(ortho[..., :3][m & covered], truth[m & covered])
                              if (m & covered).any() else None} for k, m in by_stereo.items()},
            "coverage_of_survey_area": float(covered[inside].mean()),
            "focal_px": lens["fx"], "focal_error": lens["fx"] / true_f - 1.0,
            "focal_refined": lens.get("focal_refined"), "focal_images_sigma_px": lens.get("focal_images_sigma_px"),
            "distortion": lens["distortion"][:2] if lens["distortion"] else None,
            "cameras": _camera_errors(model, cams, offset),
            "georeference": {k: ref.report(model)[k] for k in ("epsg", "camera_position_error_m", "scale")},
            "seams_picture": str(picture.relative_to(RESULTS_DIR.parent)),
            "coverage_of_registered_footprints": {k: v for k, v in model.report["mapping"]["coverage"].items()
                                                  if k != "note"},
        })
        res.discard_work()
        out["gps_prior"] = _gps_prior_trial(frames, cams, work)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return out, _synthetic_md(out)


STEREO_LABELS = {"measured": "heights measured by the dense cloud",
                 "filled": "heights filled where no dense point reaches (fewer photos saw it than a point needs)"}


def _stereo_cells(points: np.ndarray, grid, factor: int) -> np.ndarray:
    """(H, W) bool on the orthophoto's grid: the cells whose heights the dense cloud measured (a DSM cell with
    dense points, or a gap of at most 3 cells between such cells); the other covered cells' heights are filled
    (the footprints' edges, which fewer than ``dense_min_views`` photos saw)."""
    from workers.drone.surface import Grid, cell_medians, coverage_mask

    g = Grid(grid.x0, grid.y0, grid.gsd * factor, -(-grid.width // factor), -(-grid.height // factor))
    _, counts = cell_medians(np.asarray(points, np.float64), g)
    cells = np.repeat(np.repeat(coverage_mask(counts, 3), factor, axis=0), factor, axis=1)
    return cells[:grid.height, :grid.width]


def _gps_prior_trial(frames, cams, work: Path) -> dict[str, Any]:
    """Sparse model + georeference from GPS with 1 m noise per axis: similarity alone against a bundle
    adjustment with the GPS as a prior of 1 m and 3 m; absolute camera error against the truth."""
    from workers.synth.survey import write_geotagged_stills

    folder = work / "noisy"
    write_geotagged_stills(folder, frames, cams, SYNTH_EPSG, SYNTH_ORIGIN, focal_35mm=SYNTH_F35, gps_noise_m=1.0,
                           seed=7)
    out = {"gps_noise_m": 1.0}
    for name, sigma in (("similarity_only", None), ("prior_1m", 1.0), ("prior_3m", 3.0)):
        res = run_pipeline(folder, ReconstructionParams(orthophoto=False, dsm=False, gps_prior_m=sigma))
        offset = res.georef.origin - np.asarray(SYNTH_ORIGIN)
        out[name] = _camera_errors(res.model, cams, offset)
        res.discard_work()
    return out


def _synthetic_md(o: dict[str, Any]) -> str:
    d = o["dsm_error_gsd"]
    c = o["cameras"]
    rows = [
        ["DSM error, median abs (GSD)", d["median_abs"], f"<= {DSM_GOAL_GSD:g}",
         "met" if d["median_abs"] <= DSM_GOAL_GSD else "**not met**"],
        ["DSM error, RMSE (GSD)", d["rmse"], "", ""],
        ["DSM cells within 1 GSD", d["within_1"], "", ""],
        ["orthophoto PSNR, covered cells (dB)", o["orthophoto_psnr_db"], f">= {ORTHO_GOAL_DB:g}",
         "met" if o["orthophoto_psnr_db"] >= ORTHO_GOAL_DB else "**not met**"],
        ["orthophoto PSNR after the best sub-pixel shift (dB)", o["orthophoto_psnr_aligned_db"], "", ""],
        *[[f"orthophoto PSNR, {k.replace('_', ' ')} ({o['orthophoto_region_share'][k]:.0%} of the cells) (dB)", v,
           "", ""] for k, v in o["orthophoto_psnr_by_region_db"].items()],
        *[[f"{STEREO_LABELS[k]} ({v['share_of_covered']:.0%} of the covered cells): DSM median abs (GSD) / "
           "orthophoto PSNR (dB)", f"{v['dsm_median_abs_gsd']:.3f} / {v['orthophoto_psnr_db']:.2f}", "", ""]
          for k, v in o["by_stereo"].items() if v["dsm_median_abs_gsd"] is not None],
        ["coverage of the surveyed area", o["coverage_of_survey_area"], "", ""],
        ["focal length found (px) / true", f"{o['focal_px']:.1f} / {o['true_focal_px']:.1f}",
         f"within {FOCAL_GOAL:.0%}", "met" if abs(o["focal_error"]) <= FOCAL_GOAL else "**not met**"],
        ["k1, k2 found / true", f"{o['distortion']} / {o['true_distortion']}", "", ""],
        ["camera centres against the truth, RMSE (m)", c["absolute_rmse_m"], "", ""],
    ]
    g = o["gps_prior"]
    prior_rows = [[name, g[name]["absolute_rmse_m"], g[name]["absolute_max_m"], g[name]["ate_after_similarity_m"]]
                  for name in ("similarity_only", "prior_1m", "prior_3m")]
    t = o["timings_s"]
    return (f"### Synthetic nadir survey ({o['images']} geotagged JPEGs {o['size'][0]}x{o['size'][1]} at "
            f"{o['altitude_m']:g} m over {o['area_m'][0]:g} x {o['area_m'][1]:g} m, lens k1 {SYNTH_DIST[0]}, "
            f"k2 {SYNTH_DIST[1]}, no intrinsics given; GSD {o['gsd_m'] * 100:.1f} cm)\n\n"
            + md_table(["measure", "value", "goal", ""], rows)
            + f"\n\nThe truth: the scene ray-cast straight from above on the job's own grid (each cell the mean of 3 x 3 "
              f"rays over its area; the DSM the top surface's height at each cell's centre); GPS exact in EXIF. The "
              f"orthophoto lies {np.hypot(*o['orthophoto_shift_to_truth_px']):.2f} cells from the truth (phase "
              f"correlation). Job {o['job_s']} s (load {o['load_average']}); stages (s): "
              + ", ".join(f"{k} {v:.1f}" for k, v in t.items())
              + f".\n\nSeams, DSM error: `{o['seams_picture']}` (truth | orthophoto, seams between frames in red | DSM "
                "error, -2 GSD cyan to +2 GSD magenta).\n\n"
              + f"GPS as a bundle-adjustment prior (sparse model, GPS with {g['gps_noise_m']:g} m noise per axis; camera "
                "centres against the truth, m):\n\n"
              + md_table(["georeference", "absolute RMSE", "absolute max", "ATE after similarity"], prior_rows) + "\n")


# ---------------------------------------------------------------------------------------------
# 2. The real stills
# ---------------------------------------------------------------------------------------------
def _gps_utm(folder: Path, names: list[str]) -> tuple[np.ndarray, int]:
    from workers.drone.exif import read_photo_meta
    from workers.drone.geo import to_projected, utm_epsg

    gps = [read_photo_meta((folder / n).read_bytes()).gps for n in names]
    epsg = utm_epsg(float(np.mean([g.lat for g in gps])), float(np.mean([g.lon for g in gps])))
    return to_projected(gps, epsg), epsg


def _ate_vs_gps(model, names: list[str], gps: np.ndarray, origin: np.ndarray) -> dict[str, Any]:
    idx = {n: i for i, n in enumerate(names)}
    reg = [f for f in np.flatnonzero(model.registered) if model.frame_name[f] in idx]
    C = np.stack([camera_centre(model.R[f], model.t[f]) for f in reg]) + origin
    return _ate(C, gps[[idx[model.frame_name[f]] for f in reg]])


def _ate(C: np.ndarray, G: np.ndarray) -> dict[str, Any]:
    """ATE of the camera centres C (N, 3) against the GPS G (N, 3, in flight order) after a similarity, and how its
    residual splits: horizontal and vertical RMSE; the mean sideways offset relative to the heading (a principal
    point off the image centre shifts every line sideways, alternating as the camera turns around); half the
    difference between the mean height residual of the frames flying one way and of those flying back."""
    err = trajectory_error(C, G)
    res = err.alignment.apply(C) - G
    heading = np.gradient(G[:, :2], axis=0)
    heading /= np.maximum(np.linalg.norm(heading, axis=1, keepdims=True), 1e-9)
    sideways = res[:, 1] * heading[:, 0] - res[:, 0] * heading[:, 1]  # positive: left of the heading
    axis = np.linalg.svd(heading, full_matrices=False)[2][0]  # the flight lines' direction (either sign)
    one_way = heading @ axis > 0.5
    back = heading @ axis < -0.5
    by_direction = (res[one_way, 2].mean() - res[back, 2].mean()) / 2 if one_way.any() and back.any() else None
    return {"ate_m": err.ate_rmse, "ate_max_m": err.ate_max, "registered": len(C),
            "horizontal_m": float(np.sqrt(np.mean(np.sum(res[:, :2] ** 2, axis=1)))),
            "vertical_m": float(np.sqrt(np.mean(res[:, 2] ** 2))),
            "sideways_bias_m": float(sideways.mean()),
            "height_by_direction_m": None if by_direction is None else abs(float(by_direction))}


PYCOLMAP_RUNS = {
    "pycolmap_selfcal": ("pycolmap, its own self-calibration (SIMPLE_RADIAL: f, k)", {}),
    "pycolmap_focal_held": ("pycolmap, focal length held at its EXIF prior, k refined",
                            {"ba_refine_focal_length": False}),
    "pycolmap_selfcal_principal_point": ("pycolmap, f, k and principal point refined",
                                         {"ba_refine_principal_point": True}),
}
"""pycolmap's incremental mapping on one feature database, with its bundle adjustment's options as given."""


def _pycolmap_runs(folder: Path, names: list[str], gps: np.ndarray) -> dict[str, dict[str, Any]]:
    """pycolmap on the same stills: SIMPLE_RADIAL from its EXIF prior, sequential matching (overlap 10), then
    incremental mapping once per :data:`PYCOLMAP_RUNS` (the features and matches shared; each run's seconds are
    its mapping's, the first also the extraction's and matching's)."""
    out = {}
    with tempfile.TemporaryDirectory() as d:
        db = Path(d) / "database.db"
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "SIMPLE_RADIAL"
        t0 = time.perf_counter()
        pycolmap.extract_features(db, folder, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                                  reader_options=reader, device=pycolmap.Device.cpu)
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = 10
        pycolmap.match_sequential(db, pairing_options=pairing, device=pycolmap.Device.cpu)
        features_s = time.perf_counter() - t0
        for key, (_, settings) in PYCOLMAP_RUNS.items():
            options = pycolmap.IncrementalPipelineOptions()
            for name, value in settings.items():
                setattr(options, name, value)
            load0 = load_average(2)
            t1 = time.perf_counter()
            maps = pycolmap.incremental_mapping(db, folder, Path(d) / key, options)
            seconds = time.perf_counter() - t1 + (features_s if not out else 0.0)
            out[key] = {**_pycolmap_ate(max(maps.values(), key=lambda r: r.num_reg_images()), names, gps),
                        "seconds": seconds, "load_average": [load0, load_average(2)]}
    return out


def _pycolmap_ate(rec, names: list[str], gps: np.ndarray) -> dict[str, Any]:
    idx = {n: i for i, n in enumerate(names)}
    C, G = [], []
    for img in sorted(rec.images.values(), key=lambda i: idx.get(i.name, -1)):  # flight order, for the headings
        if img.has_pose and img.name in idx:
            pose = img.cam_from_world()
            C.append(camera_centre(pose.rotation.matrix(), np.asarray(pose.translation)))
            G.append(gps[idx[img.name]])
    cam = next(iter(rec.cameras.values()))
    return {**_ate(np.stack(C), np.stack(G)), "focal_px": float(cam.params[0]),
            "principal_point_px": [float(cam.params[1]), float(cam.params[2])], "k": float(cam.params[3]),
            "points": rec.num_points3D()}


def real_stills(quick: bool) -> tuple[dict[str, Any], str]:
    folder = dataset("sfm", "drone_fc350", "images")
    if folder is None:
        return {"skipped": "sfm/drone_fc350 not found"}, "sfm/drone_fc350 not found: skipped.\n"
    names = sorted(p.name for p in folder.iterdir() if p.suffix.upper() == ".JPG")
    work = Path(tempfile.mkdtemp(prefix="mapping_fc350_"))
    try:
        media = folder
        if quick:
            names = names[:12]
            media = work / "images"
            media.mkdir()
            for n in names:
                os.symlink(folder / n, media / n)
        gps, epsg = _gps_utm(folder, names)
        out: dict[str, Any] = {"images": len(names), "epsg": epsg}
        # The whole job, no parameters: what a user gets.
        load0 = load_average(2)
        t0 = time.perf_counter()
        res = run_pipeline(media, ReconstructionParams())
        files = work / "out"
        files.mkdir()
        write_outputs(res, lambda n: files / n)
        res.discard_work()
        job_s = time.perf_counter() - t0
        model = res.model
        lens = model.report["intrinsics"]
        geo = model.report["georeference"]
        out["ours_selfcal"] = {
            **_ate_vs_gps(model, names, gps, res.georef.origin), "job_s": round(job_s, 1),
            "load_average": [load0, load_average(2)], "timings_s": model.report["timings_s"],
            "focal_px": lens["fx"], "focal_source": lens["source"], "focal_refined": lens["focal_refined"],
            "principal_point_px": [lens["cx"], lens["cy"]], "principal_point_start_px": lens["principal_point_start_px"],
            "focal_conflict_sigmas": lens["focal_conflict_sigmas"],
            "focal_images_sigma_px": lens["focal_images_sigma_px"], "distortion": lens["distortion"][:2],
            "camera_position_error_m": geo["camera_position_error_m"], "gsd_m": model.report["mapping"]["gsd"],
            "dense_points": model.report["dense"]["points"], "files": sorted(p.name for p in files.iterdir())}
        for name, target in (("orthophoto.png", "mapping_fc350_orthophoto.png"), ("dsm.png", "mapping_fc350_dsm.png")):
            _small_copy(files / name, RESULTS_DIR / target)
        # The sparse model alone: given intrinsics, and self-calibrated with the GPS as a BA prior.
        runs = {"ours_given_intrinsics": dict(fx=702.0, fy=702.0, cx=599.5, cy=449.5), "ours_selfcal_centre_held": {},
                "ours_selfcal_gps_prior_2m": dict(gps_prior_m=2.0)}
        # Where the lines' height pattern lies: the focal length held at other values (the lens otherwise as found),
        # and the GPS prior at growing weights.
        found = dict(cx=lens["cx"], cy=lens["cy"], distortion=list(lens["distortion"]), refine_intrinsics=False)
        runs.update({f"ours_focal_held_{f:g}": dict(fx=f, fy=f, **found) for f in HELD_FOCALS})
        runs.update({f"ours_selfcal_gps_prior_{m:g}m": dict(gps_prior_m=m) for m in PRIOR_SIGMAS})
        for key, params in runs.items():
            t1 = time.perf_counter()
            with _principal_point_held(key == "ours_selfcal_centre_held"):
                r = run_pipeline(media, ReconstructionParams(orthophoto=False, dsm=False, **params))
            r.discard_work()
            out[key] = {**_ate_vs_gps(r.model, names, gps, r.georef.origin),
                        "seconds": round(time.perf_counter() - t1, 1), "focal_px": r.model.report["intrinsics"]["fx"]}
        out["flight_speed_m_s"] = _flight_speed(folder, names, gps)
        out["gps_altitude_m"] = {"mean": float(gps[:, 2].mean()), "range": float(np.ptp(gps[:, 2]))}
        if pycolmap is not None:
            out.update(_pycolmap_runs(media, names, gps))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return out, _real_md(out)


def _flight_speed(folder: Path, names: list[str], gps: np.ndarray) -> float | None:
    """Median ground speed (m/s) between consecutive shots: the GPS distance over the EXIF DateTimeOriginal gap
    (whole seconds), over the pairs one to 20 s apart."""
    from PIL import Image

    def shot_time(name: str) -> float | None:
        text = Image.open(folder / name).getexif().get_ifd(0x8769).get(36867)
        return time.mktime(time.strptime(text, "%Y:%m:%d %H:%M:%S")) if text else None

    times = [shot_time(n) for n in names]
    speeds = [float(np.linalg.norm(gps[i + 1, :2] - gps[i, :2])) / (times[i + 1] - times[i])
              for i in range(len(names) - 1)
              if times[i] is not None and times[i + 1] is not None and 1 <= times[i + 1] - times[i] <= 20]
    return float(np.median(speeds)) if speeds else None


@contextlib.contextmanager
def _principal_point_held(held: bool):
    """With ``held``, the self-calibration's principal point held at the image centre (its prior made 1e-9 of the
    image's side): the lens as it was refined before the principal point was."""
    saved = reconstruction.CENTRE_PRIOR_SIGMA
    reconstruction.CENTRE_PRIOR_SIGMA = 1e-9 if held else saved
    try:
        yield
    finally:
        reconstruction.CENTRE_PRIOR_SIGMA = saved


def _small_copy(src: Path, dst: Path, side: int = 900) -> None:
    img = cv2.imread(str(src), cv2.IMREAD_UNCHANGED)
    s = min(1.0, side / max(img.shape[:2]))
    cv2.imwrite(str(dst), cv2.resize(img, None, fx=s, fy=s, interpolation=cv2.INTER_AREA),
                [cv2.IMWRITE_PNG_COMPRESSION, 9])


def _real_md(o: dict[str, Any]) -> str:
    s = o["ours_selfcal"]
    rows = []
    for key, label in (("ours_selfcal", "ours, no intrinsics (self-calibrated, the job's defaults)"),
                       ("ours_selfcal_centre_held", "ours, self-calibrated, principal point held at the centre"),
                       ("ours_given_intrinsics", "ours, given K (f 702, no distortion)"),
                       ("ours_selfcal_gps_prior_2m", "ours, self-calibrated + GPS as a 2 m BA prior (circular)"),
                       *((k, label) for k, (label, _) in PYCOLMAP_RUNS.items())):
        if key in o:
            r = o[key]
            split = [r.get(k) for k in ("horizontal_m", "vertical_m", "sideways_bias_m", "height_by_direction_m")]
            rows.append([label, f"{r['registered']}/{o['images']}", r["ate_m"], r["ate_max_m"], *split,
                         r["focal_px"]])
    lo, hi = FC350_FOCAL
    f = s["focal_px"]
    off = max(lo - f, f - hi, 0.0) / (lo if f < lo else hi)
    pc = o.get("pycolmap_selfcal")
    ate_ok = pc is not None and s["ate_m"] <= pc["ate_m"]
    goals = [
        ["focal length within 3 % of the EXIF value (693.3-702.1 px)", f"{f:.1f} px ({off:.1%} outside the range)",
         "met" if off <= FOCAL_GOAL else "**not met**"],
        ["ATE against GPS <= pycolmap's self-calibrated", f"{s['ate_m']:.2f} m against "
         + (f"{pc['ate_m']:.2f} m (horizontal {s['horizontal_m']:.2f} against {pc['horizontal_m']:.2f} m, vertical "
            f"{s['vertical_m']:.2f} against {pc['vertical_m']:.2f} m)" if pc else "(pycolmap not installed)"),
         "met" if ate_ok else "**not met**"],
        [f"whole job on {o['images']} stills <= {JOB_GOAL_S:g} s on 2 cores",
         f"{s['job_s']} s (1-min load {s['load_average']})", "met" if s["job_s"] <= JOB_GOAL_S else "**not met**"],
    ]
    cp = s["camera_position_error_m"]
    t = s["timings_s"]
    return (f"### sfm/drone_fc350: the job with no parameters ({o['images']} stills 1200x900, EXIF GPS; EPSG:{o['epsg']})"
            "\n\n" + md_table(["run", "registered", "ATE vs GPS (m)", "max (m)", "horizontal (m)", "vertical (m)",
                               "sideways of the heading (m)", "height by direction (m)", "focal (px)"], rows)
            + "\n\n" + md_table(["goal", "measured", ""], goals) + "\n" + _height_pattern_md(o)
            + "\n\nATE: RMSE of the camera centres against the EXIF GPS (UTM) after a least-squares similarity, for "
              "every run alike; the GPS itself is consumer-grade (metre-level, with a pattern along the flight lines). "
              "Its residual split: horizontal and vertical RMSE; the mean offset to the left of the heading (the "
              "camera turns around with each line, so a principal point off the image centre moves every line "
              "sideways); half the difference between the mean height residual of the lines flown one way and of "
              "those flown back (every reconstruction shows it, scaled by its own focal length: below). "
              + (f"Here pycolmap's height pattern is {pc['height_by_direction_m'] / s['height_by_direction_m']:.2f} of "
                 f"ours and its focal length {pc['focal_px'] / s['focal_px']:.2f} of ours: its lower ATE is that "
                 "flattening, while its horizontal error is larger. "
                 if pc and pc.get("height_by_direction_m") and s.get("height_by_direction_m") else "")
              + (f"With its focal length held at its EXIF prior, pycolmap's ATE is {o['pycolmap_focal_held']['ate_m']:.2f} m "
                 f"(horizontal {o['pycolmap_focal_held']['horizontal_m']:.2f} m, vertical "
                 f"{o['pycolmap_focal_held']['vertical_m']:.2f} m); with the principal point refined too, "
                 f"{o['pycolmap_selfcal_principal_point']['ate_m']:.2f} m (focal "
                 f"{o['pycolmap_selfcal_principal_point']['focal_px']:.0f} px, principal point "
                 f"({o['pycolmap_selfcal_principal_point']['principal_point_px'][0]:.1f}, "
                 f"{o['pycolmap_selfcal_principal_point']['principal_point_px'][1]:.1f}) px). "
                 if "pycolmap_focal_held" in o and "pycolmap_selfcal_principal_point" in o else "")
              + (f"Our principal point: ({s['principal_point_px'][0]:.1f}, {s['principal_point_px'][1]:.1f}) px "
                 f"from ({s['principal_point_start_px'][0]:.1f}, {s['principal_point_start_px'][1]:.1f}). "
                 if "principal_point_px" in s else "")
              + f"Our focal length: source {s['focal_source']}; the images alone determine it to "
              f"{s['focal_images_sigma_px']:.1f} px (sigma), "
              + (f"refined under the prior (what they alone say lies {s['focal_conflict_sigmas']:.1f} sigmas from it)" if s["focal_refined"] else
                 f"but what they alone say lies {s['focal_conflict_sigmas']:.1f} sigmas from the EXIF value: held there (a "
                 "flat scene seen from above trades focal length against altitude and distortion; under the prior alone "
                 "it went to 635 px in our runs, pycolmap's to its value above)")
              + f"; distortion k1, k2 = {s['distortion']}. The orthophoto's camera-position error (the georeferenced "
                f"camera centres against their GPS): horizontal RMSE {cp['horizontal_rmse']:.2f} m, vertical "
                f"{cp['vertical_rmse']:.2f} m, max {cp['max']:.2f} m; GSD {s['gsd_m'] * 100:.1f} cm, "
                f"{s['dense_points']:,} dense points. Files: {', '.join(s['files'])}.\n\n"
              + "Job stages (s): " + ", ".join(f"{k} {v:.1f}" for k, v in t.items())
              + ".\n\nPictures: `benchmarks/results/mapping_fc350_orthophoto.png`, "
                "`benchmarks/results/mapping_fc350_dsm.png`.\n")


def _height_pattern_md(o: dict[str, Any]) -> str:
    """Table and reading of the lines' height pattern against the focal length and the GPS prior's weight."""
    labels = {**{f"ours_focal_held_{f:g}": f"ours, focal length held at {f:g} px" for f in HELD_FOCALS},
              "ours_selfcal": "ours, self-calibrated", "pycolmap_selfcal": "pycolmap, self-calibrated",
              **{f"ours_selfcal_gps_prior_{m:g}m": f"ours, self-calibrated + GPS prior {m:g} m"
                 for m in (2.0, *PRIOR_SIGMAS)}}  # in the table's order
    runs = [(k, o[k]) for k in labels if k in o and o[k].get("height_by_direction_m") is not None]
    if len(runs) < 3:
        return ""
    rows = [[labels[k], r["focal_px"], r["height_by_direction_m"], 100 * r["height_by_direction_m"] / r["focal_px"],
             r["ate_m"], r["horizontal_m"], r["vertical_m"]] for k, r in runs]
    per_focal = {k: 100 * r["height_by_direction_m"] / r["focal_px"] for k, r in runs if "prior" not in k}
    held = [k for k in per_focal if k.startswith("ours_focal_held")]
    selfcal = ", ".join(f"{labels[k].split(',')[0]} {per_focal[k]:.3f} (at {o[k]['focal_px']:.0f} px)"
                        for k in ("ours_selfcal", "pycolmap_selfcal") if k in per_focal)
    priors = [r for k, r in runs if "prior" in k]
    strongest = min(priors, key=lambda r: r["ate_m"]) if priors else None
    alt = o.get("gps_altitude_m", {})
    s = o["ours_selfcal"]
    speed = o.get("flight_speed_m_s")
    footprint = 900 / s["focal_px"] * alt.get("mean", float("nan"))  # metres the image's 900 rows span on the ground
    return ("\n**The lines' height pattern** (sparse model only; focal held: distortion and principal point as the "
            "self-calibration found them):\n\n"
            + md_table(["run", "focal (px)", "height by direction (m)", "per 100 px of focal length (m)", "ATE (m)",
                        "horizontal (m)", "vertical (m)"], rows)
            + f"\n\nThe pattern grows in proportion to the focal length the model is built with, through zero "
              f"(m per 100 px of focal length: self-calibrated, {selfcal}; held at "
              + ", ".join(f"{o[k]['focal_px']:.0f} px {per_focal[k]:.3f} (ATE {o[k]['ate_m']:.1f} m)" for k in held)
            + f", the lens as found at {s['focal_px']:.0f} px fitting the shorter ones less well): the images "
              f"themselves put the lines flown one way {2 * s['height_by_direction_m']:.1f} m above those flown back "
              f"(a fixed share of the altitude, {2 * s['height_by_direction_m'] / alt.get('mean', float('nan')):.1%} "
              f"of the ~{alt.get('mean', float('nan')):.0f} m EXIF altitude), while the EXIF altitude spans "
              f"{alt.get('range', float('nan')):.1f} m over the whole flight. "
            + (f"The GPS as a bundle-adjustment prior hardly moves it: at {strongest['focal_px']:.0f} px and a prior "
               f"of 0.2 m the pattern is still {strongest['height_by_direction_m']:.2f} m (the ATE falls to "
               f"{strongest['ate_m']:.2f} m only as the horizontal is pulled onto the GPS: a 0.2 m prior on "
               "metre-level GPS fits its noise, so the job's default is no prior). " if strongest else "")
            + "The camera turns around with each line (the image's top points ahead on every line), so an effect "
              "fixed to the camera could flip with the heading; a rolling shutter's is one, but "
            + (f"at the {speed:.1f} m/s the drone moved between shots a readout as long as {RS_READOUT_S * 1e3:.0f} ms "
               f"moves it {speed * RS_READOUT_S:.2f} m, {speed * RS_READOUT_S / footprint:.2%} of the {footprint:.0f} m "
               f"the image spans along the track, against a pattern of {s['height_by_direction_m'] / alt['mean']:.1%} "
               "of the altitude each way. " if speed and alt else "")
            + "What fits is the altitude record: the flight "
              "controller holds a barometric altitude, whose reading depends on the air flowing past the drone (into "
              "the wind or with it), so the recorded altitude stays flat while the real one steps with the heading. "
              "The images cannot be fitted to that record without a focal length that flattens the flight "
              "(pycolmap's lower ATE), which the focal-length goal rules out.\n")


def bench_mapping(quick: bool) -> tuple[dict[str, Any], str]:
    """Both parts; the section's results and Markdown."""
    syn, syn_md = synthetic(quick)
    real, real_md = real_stills(quick)
    return {"synthetic": syn, "drone_fc350": real}, syn_md + "\n" + real_md
