"""Sweep renderer benchmark: quality of the four colour weightings and speed of the fused kernel.

    python benchmarks/sweep.py [--quick] [--skip-speed] [--skip-data] [--skip-stereo] [--speed-only] [--stereo-only]

Quality: (1) procedural scene, virtual views between rig cameras against the analytic truth
(PSNR/SSIM inside the object); (2) a virtual camera moving along the arc across camera switches:
the largest frame-to-frame colour jump and a blur measure (Laplacian energy over the truth's);
(3) Middlebury Teddy im4 and Art view3 held out and synthesised from other views; (4)
templeSparseRing leave-one-out from ring neighbours, scored inside the object.
Speed: 10 cameras at 640x480, virtual 640x480 / 320x240, 32/64/128 planes, the fused kernel
against the straightforward per-plane cv2.warpPerspective + numpy variance, in the same run
(interleaved repeats, medians; wall and CPU time); the live configuration (320x240, 48 planes)
with and without visual hull and coarse-to-fine, with the depth error against the truth beside
each, and the per-frame extras of a stream (set_frames, JPEG encode).
Depth choice (issue 20): the sweep with each aggregation (none / window / sgm) against OpenCV SGBM +
DIBR (workers/depth/dibr.py) on Middlebury Teddy and Art, two views and all views, PSNR and bad-1px on
the same pixels, and the live configuration's speed with each aggregation (--stereo-only runs just this).
Writes benchmarks/results/sweep.json and the "sweep" section of benchmarks/RESULTS.md.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import cv2
import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import md_table, publish  # noqa: E402
from workers.camera import Camera  # noqa: E402
from workers.common.datasets import dataset  # noqa: E402
from workers.synth import arc_angles, arc_camera, camera_gains, default_arc_rig, default_scene, render, render_views  # noqa: E402
from workers.sweep.metrics import frame_jump, highfreq_ratio, psnr, ssim  # noqa: E402
from workers.sweep.reference import reference_sweep  # noqa: E402
from workers.sweep.renderer import RenderOptions, RenderResult, SweepRenderer  # noqa: E402
from workers.sweep.rig import Rig, depth_range_from_box  # noqa: E402
from workers.sweep.rig_io import load_images, load_middlebury_par, rectified_rig  # noqa: E402
from workers.sweep.silhouette import silhouette_from_background  # noqa: E402

# name -> weighting options; d_bnd of kojima is set per scene from the camera spacing
METHODS = {
    "global": {"method": "global"},
    "nearest": {"method": "nearest"},
    "ulr2": {"method": "ulr", "k": 2},
    "ulr3": {"method": "ulr", "k": 3},
    "ulr4": {"method": "ulr", "k": 4},
    "kojima": {"method": "kojima"},
}
NEAR, FAR = 1.6, 3.6  # the procedural object lies within these depths from the arc
GAIN_SPREAD = 0.06


def all_methods(renderer: SweepRenderer, first: RenderResult) -> dict[str, RenderResult]:
    """``first`` re-coloured by every method (one sweep, six colourings); kojima's D_bnd is the
    renderer's default, derived from the camera spacing."""
    return {name: renderer.reshade(first, **opts) for name, opts in METHODS.items()}


# --- procedural scene ---------------------------------------------------------------------------
def procedural_capture(size: tuple[int, int]):
    scene = default_scene()
    cams = default_arc_rig(10, width=size[0], height=size[1])
    views = render_views(scene, cams, gains=camera_gains(10, GAIN_SPREAD))
    renderer = SweepRenderer(Rig(tuple(cams)), [v.image for v in views], backgrounds=[v.background for v in views])
    return scene, renderer


def procedural_quality(scene, renderer: SweepRenderer, size, quick: bool) -> dict:
    angles = arc_angles(10, 90.0)
    pairs = [(2, 3), (5, 6)] if quick else [(1, 2), (3, 4), (5, 6), (7, 8)]
    scores: dict[str, dict[str, list[float]]] = {m: {"psnr": [], "ssim": [], "depth_mae": []} for m in METHODS}
    for a, b in pairs:
        for s in (0.25, 0.5, 0.75):
            cam = arc_camera(float(angles[a] + s * (angles[b] - angles[a])), width=size[0], height=size[1], name="v")
            gt = render(scene, cam, with_background=False)
            first = renderer.render(cam, planes=64, near=NEAR, far=FAR)
            mask = gt.silhouette & np.isfinite(first.depth)
            for name, res in all_methods(renderer, first).items():
                scores[name]["psnr"].append(psnr(res.image, gt.image, mask))
                scores[name]["ssim"].append(ssim(res.image, gt.image, mask))
                scores[name]["depth_mae"].append(float(np.mean(np.abs(res.depth[mask] - gt.depth[mask]))))
    out = {m: {"psnr_db": float(np.mean(v["psnr"])), "ssim": float(np.mean(v["ssim"])),
               "depth_mae_m": float(np.mean(v["depth_mae"])), "views": len(v["psnr"])} for m, v in scores.items()}
    return out


def temporal(scene, renderer: SweepRenderer, size, quick: bool) -> dict:
    """A virtual camera moving along the arc from camera 2 to camera 6 in small steps."""
    angles = arc_angles(10, 90.0)
    step = 1.0 if quick else 0.5
    path = np.arange(angles[2], angles[6] + 1e-9, step)
    prev: dict[str, np.ndarray] = {}
    prev_gt = prev_mask = None
    stats = {m: {"jumps": [], "excess": [], "hf": [], "psnr": []} for m in METHODS}
    gt_jumps = []
    for k, ang in enumerate(path):
        cam = arc_camera(float(ang), width=size[0], height=size[1], name=f"f{k}")
        gt = render(scene, cam, with_background=False)
        first = renderer.render(cam, planes=64, near=NEAR, far=FAR)
        mask = gt.silhouette & np.isfinite(first.depth)
        results = all_methods(renderer, first)
        if prev_gt is not None:
            both = mask & prev_mask
            gj = frame_jump(prev_gt, gt.image, both)
            gt_jumps.append(gj)
        for name, res in results.items():
            stats[name]["hf"].append(highfreq_ratio(res.image, gt.image, mask))
            stats[name]["psnr"].append(psnr(res.image, gt.image, mask))
            if prev_gt is not None:
                j = frame_jump(prev[name], res.image, both)
                stats[name]["jumps"].append(j)
                stats[name]["excess"].append(j - gj)
            prev[name] = res.image
        prev_gt, prev_mask = gt.image, mask
    out = {m: {"max_jump": float(np.max(v["jumps"])), "max_excess_jump": float(np.max(v["excess"])),
               "mean_jump": float(np.mean(v["jumps"])), "blur_hf_ratio": float(np.mean(v["hf"])),
               "psnr_db": float(np.mean(v["psnr"]))} for m, v in stats.items()}
    out["truth"] = {"max_jump": float(np.max(gt_jumps)), "mean_jump": float(np.mean(gt_jumps)), "frames": len(path),
                    "step_deg": step}
    return out


# --- Middlebury rectified sets ------------------------------------------------------------------
def leave_one_out(files: dict[int, str], sources: list[int], target: int, w: int, h: int) -> tuple[Rig, Camera]:
    """The rectified rig of views ``sources`` (positions = view numbers) and the held-out camera ``target``."""
    views = sorted(sources + [target])
    rig = rectified_rig([files[k] for k in views], w, h, positions=views)
    inputs = Rig(tuple(c for c, k in zip(rig.cameras, views) if k != target),
                 tuple(f for f, k in zip(rig.image_files, views) if k != target))
    return inputs, rig.cameras[views.index(target)]


def rectified_quality(folder: Path, prefix: str, target: int, sets: dict[str, list[int]], disp_file: str,
                      disp_div: float, disp_baselines: int, planes: int) -> dict:
    """Hold out view ``target`` and synthesise it from each set of views (PSNR/SSIM per method).

    The depth range comes from the ground-truth disparity's 0.5-99.5 percentiles (+-10%), converted
    to depth with f = image width and a unit baseline."""
    files = {int(p.stem[len(prefix):]): p.name for p in folder.glob(f"{prefix}*.png") if p.stem[len(prefix):].isdigit()}
    disp = cv2.imread(str(folder / disp_file), cv2.IMREAD_UNCHANGED).astype(np.float64)
    d1 = disp[disp > 0] / disp_div / disp_baselines
    lo, hi = np.percentile(d1, [0.5, 99.5])
    target_img = cv2.imread(str(folder / files[target]))
    h, w = target_img.shape[:2]
    near, far = w / (hi * 1.1), w / (lo * 0.9)
    out = {}
    for set_name, idx in sets.items():
        inputs, virtual = leave_one_out(files, idx, target, w, h)
        renderer = SweepRenderer(inputs, load_images(inputs, folder))
        first = renderer.render(virtual, planes=planes, near=near, far=far)
        mask = np.isfinite(first.depth)
        res = all_methods(renderer, first)
        out[set_name] = {m: {"psnr_db": psnr(r.image, target_img, mask), "ssim": ssim(r.image, target_img, mask)}
                         for m, r in res.items()}
        out[set_name]["coverage"] = float(mask.mean())
    return out


def temple_quality(folder: Path, quick: bool, planes: int) -> dict:
    """templeSparseRing leave-one-out from the 2 or 4 nearest ring neighbours (the twin view of the
    same pose excluded), scored inside the held-out view's object silhouette."""
    rig = load_middlebury_par(folder / "templeSR_par.txt")
    images = load_images(rig, folder)
    lo = np.array([-0.073568, 0.021728, -0.012445])  # the dataset README's bounding box
    hi = np.array([0.028855, 0.181892, 0.062736])
    centre = (lo + hi) / 2
    dirs = rig.centers() - centre
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    targets = range(len(rig)) if not quick else [2, 5, 9, 13]
    out: dict = {}
    for n_nb in (2, 4):
        per: dict[str, list] = {m: [] for m in METHODS}
        per_ssim: dict[str, list] = {m: [] for m in METHODS}
        for t in targets:
            twin = np.linalg.norm(rig.centers() - rig.centers()[t], axis=1) < 1e-6
            ang = np.arccos(np.clip(dirs @ dirs[t], -1, 1))
            ang[twin] = np.inf
            nb = list(np.argsort(ang)[:n_nb])
            sub = Rig(tuple(rig.cameras[i] for i in nb), tuple(rig.image_files[i] for i in nb))
            imgs = [images[i] for i in nb]
            sils = [silhouette_from_background(im, np.zeros_like(im), 70.0) for im in imgs]
            renderer = SweepRenderer(sub, imgs, silhouettes=sils)
            virtual = rig.cameras[t]
            near, far = depth_range_from_box(virtual, lo, hi)
            first = renderer.render(virtual, planes=planes, near=near, far=far)
            target_sil = silhouette_from_background(images[t], np.zeros_like(images[t]), 70.0)
            mask = target_sil & np.isfinite(first.depth)
            for name, res in all_methods(renderer, first).items():
                per[name].append(psnr(res.image, images[t], mask))
                per_ssim[name].append(ssim(res.image, images[t], mask))
        out[f"ring{n_nb}"] = {m: {"psnr_db": float(np.mean(per[m])), "ssim": float(np.mean(per_ssim[m]))}
                              for m in METHODS}
        out[f"ring{n_nb}"]["targets"] = len(list(targets))
    return out


# --- speed --------------------------------------------------------------------------------------
def clocked(fn) -> tuple[float, float, object]:
    """(wall s, CPU s of this process (all threads), result) of one call."""
    c0, t0 = time.process_time(), time.perf_counter()
    res = fn()
    return time.perf_counter() - t0, time.process_time() - c0, res


def interleaved(fns: dict, reps: dict, warm: tuple[str, ...] = ("render",)) -> dict:
    """Calls each function ``reps[name]`` times (those in ``warm`` once more first, untimed: compiled
    code loads on the first call), interleaved so that the load other users put on the machine
    affects all of them alike. Returns per name the median wall s, the median CPU s and the last result."""
    out = {name: {"wall": [], "cpu": [], "res": fn() if name in warm else None} for name, fn in fns.items()}
    for k in range(max(reps.values())):
        for name, fn in fns.items():
            if k < reps[name]:
                wall, cpu, res = clocked(fn)
                out[name]["wall"].append(wall)
                out[name]["cpu"].append(cpu)
                out[name]["res"] = res
    return {name: {"wall": float(np.median(v["wall"])), "cpu": float(np.median(v["cpu"])), "res": v["res"]}
            for name, v in out.items()}


def speed(quick: bool) -> dict:
    scene = default_scene()
    cams = default_arc_rig(10, width=640, height=480)
    views = render_views(scene, cams)
    images = [v.image for v in views]
    full = SweepRenderer(Rig(tuple(cams)), images)
    hull = SweepRenderer(Rig(tuple(cams)), images, backgrounds=[v.background for v in views])
    angles = arc_angles(10, 90.0)
    ang = float((angles[3] + angles[4]) / 2)
    configs = [(320, 240, 32), (640, 480, 32)] if quick else \
        [(w, h, p) for (w, h) in ((320, 240), (640, 480)) for p in (32, 64, 128)]
    out: dict = {}
    for w, h, p in configs:
        cam = arc_camera(ang, width=w, height=h, name="v")
        # equal output: the reference samples at OpenCV's 1/32 px positions and chooses each pixel alone, so does the sweep here
        opts = RenderOptions(planes=p, near=NEAR, far=FAR, subpixel_bits=5, aggregation="none")
        planes = full.depth_planes(cam, p, NEAR, FAR)
        big = w * h * p > 640 * 480 * 64
        renders: list[RenderResult] = []
        m = interleaved({"render": lambda: renders.append(full.render(cam, opts)) or renders[-1],
                         "reference": lambda: reference_sweep(cams, images, cam, planes)[0]},
                        {"render": 5 if big else 9, "reference": 1 if big or quick else 2})
        t_sweep = float(np.median([r.timings["sweep_ms"] for r in renders[1:]])) / 1e3  # the sweep stage alone
        res, ref_best = m["render"]["res"], m["reference"]["res"]
        seen = all_cameras_see(cams, cam, res.planes, ref_best)
        samples = w * h * p * len(cams)
        out[f"{w}x{h}_p{p}"] = {
            "fps": 1.0 / m["render"]["wall"], "sweep_s": t_sweep, "render_s": m["render"]["wall"],
            "render_cpu_s": m["render"]["cpu"], "reference_s": m["reference"]["wall"],
            "reference_cpu_s": m["reference"]["cpu"],
            "msamples_per_s": samples / t_sweep / 1e6, "reference_msamples_per_s": samples / m["reference"]["wall"] / 1e6,
            "speedup_vs_reference": m["reference"]["wall"] / t_sweep,
            "speedup_total_vs_reference": m["reference"]["wall"] / m["render"]["wall"],
            "speedup_cpu_time_vs_reference": m["reference"]["cpu"] / m["render"]["cpu"],
            "depth_agreement": float((res.plane_index[seen] == ref_best[seen]).mean()),
            "depth_agreement_pm1": float((np.abs(res.plane_index[seen] - ref_best[seen]) <= 1).mean()),
            "pixels_seen_by_all": float(seen.mean()),
            "load_average": os.getloadavg()[0],
        }
        print(f"  speed {w}x{h} p{p}: {out[f'{w}x{h}_p{p}']['speedup_vs_reference']:.1f}x", flush=True)
    out["search_lanes_vs_pixel"] = lanes_vs_pixel(full, hull, ang, quick)
    out.update(live(scene, cams, images, full, hull, ang, quick))
    return out


def lanes_vs_pixel(full: SweepRenderer, hull: SweepRenderer, ang: float, quick: bool) -> dict:
    """The depth search alone (variance cost, 1/32 px positions): the 16-lane LLVM vector search against
    the best plain-numba search (pixel by pixel, the same exact pruning and plane order), on the same
    windows, interleaved. The lanes are kept only while they are >= 1.3x faster; both must choose the
    same plane at every pixel."""
    configs = [(320, 240, 48, False), (320, 240, 48, True)] if quick else \
        [(640, 480, 32, False), (640, 480, 128, False), (320, 240, 48, False), (320, 240, 48, True)]
    out = {}
    for w, h, p, use_hull in configs:
        r = hull if use_hull else full
        cam = arc_camera(ang, width=w, height=h, name="v")
        opts = RenderOptions(planes=p, near=NEAR, far=FAR, subpixel_bits=5, aggregation="none")
        s_planes = 1.0 / r.depth_planes(cam, p, NEAR, FAR)
        Q, B, _ = r._geometry(cam)
        lo, hi = r._search_window(Q, B, h, w, s_planes, use_hull)
        m = interleaved({name: (lambda lanes=lanes: r._sweep(Q, B, cam.center, s_planes, use_hull, opts, lo, hi, lanes))
                         for name, lanes in (("lanes", True), ("pixel", False))}, {"lanes": 7, "pixel": 7},
                        warm=("lanes", "pixel"))
        same = bool(np.array_equal(m["lanes"]["res"][0], m["pixel"]["res"][0]))
        out[f"{w}x{h}_p{p}" + ("_hull" if use_hull else "")] = {
            "lanes_ms": m["lanes"]["wall"] * 1e3, "pixel_ms": m["pixel"]["wall"] * 1e3,
            "speedup": m["pixel"]["wall"] / m["lanes"]["wall"], "same_choice": same}
    return out


def live(scene, cams, images, full: SweepRenderer, hull: SweepRenderer, ang: float, quick: bool) -> dict:
    """The live configuration: 320x240, 48 planes, 10 cameras, with and without the shortcuts, the
    depth error against the analytic truth beside each; plus the per-frame cost of new frames
    (set_frames: silhouettes by background subtraction) and of a JPEG encode, for the streaming budget."""
    cam = arc_camera(ang, width=320, height=240, name="live")
    gt = render(scene, cam, with_background=False)
    planes = 48
    reps = 5 if quick else 15
    m_ref = interleaved({"reference": lambda: reference_sweep(cams, images, cam, full.depth_planes(cam, planes, NEAR, FAR))},
                        {"reference": 1})
    out: dict = {}
    for name, renderer, extra in (("live_320x240_p48_full", full, {}), ("live_320x240_p48_hull", hull, {}),
                                  ("live_320x240_p48_hull_c2f", hull, {"coarse_to_fine": True})):
        opts = RenderOptions(planes=planes, near=NEAR, far=FAR, **extra)
        results = []
        m = interleaved({"render": lambda: results.append(renderer.render(cam, opts)) or results[-1]},
                        {"render": 3 if name.endswith("full") else reps})
        res = m["render"]["res"]
        stages = {k: float(np.median([r.timings.get(k, 0.0) for r in results])) for k in res.timings}
        ok = gt.silhouette & np.isfinite(res.depth)
        err = np.abs(res.depth[ok] - gt.depth[ok])
        one_step = float(np.median(np.abs(res.planes[:-1] - res.planes[1:])))
        out[name] = {"fps": 1.0 / m["render"]["wall"], "render_s": m["render"]["wall"],
                     "render_cpu_s": m["render"]["cpu"], "stages_ms": stages,
                     "reference_s": m_ref["reference"]["wall"],
                     "speedup_vs_reference": m_ref["reference"]["wall"] / m["render"]["wall"],
                     "depth_median_abs_err_m": float(np.median(err)),
                     "depth_within_2_planes": float(np.mean(err < 2 * one_step)),
                     "object_coverage": float(ok.sum() / gt.silhouette.sum()),
                     "psnr_db_kojima_object": psnr(res.image, gt.image, ok), "load_average": os.getloadavg()[0]}
        print(f"  {name}: {out[name]['fps']:.1f} fps", flush=True)
    frame = hull.render(cam, RenderOptions(planes=planes, near=NEAR, far=FAR, coarse_to_fine=True)).image
    m = interleaved({"set_frames": lambda: hull.set_frames(images),
                     "jpeg": lambda: cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 80])},
                    {"set_frames": 5, "jpeg": 20}, warm=("set_frames", "jpeg"))
    out["live_per_frame_extras"] = {"set_frames_10_cameras_ms": m["set_frames"]["wall"] * 1e3,
                                    "jpeg_encode_320x240_ms": m["jpeg"]["wall"] * 1e3}
    return out


def all_cameras_see(cams, virtual, depths: np.ndarray, best: np.ndarray) -> np.ndarray:
    """(h, w) bool: pixels whose reference-chosen point every camera sees inside its image."""
    h, w = best.shape
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    uv = np.stack([u.ravel(), v.ravel()], axis=1)
    z = np.where(best >= 0, depths[np.maximum(best, 0)], np.nan).ravel()
    X = virtual.backproject(uv, np.nan_to_num(z, nan=1.0))
    ok = np.isfinite(z)
    for c in cams:
        p, zc = c.project(X)
        ok &= (zc > 0) & (p[:, 0] >= 0) & (p[:, 1] >= 0) & (p[:, 0] <= c.width - 1) & (p[:, 1] <= c.height - 1)
    return ok.reshape(h, w)


# --- depth choice against a classic stereo pipeline (issue 20) --------------------------------------
AGGREGATIONS = ("none", "window", "sgm")
STEREO_CASES = {  # name -> folder, prefix, target, GT disparity files (view -> file, divisor), input sets
    "teddy": ("teddy", "im", 4, {2: "disp2.pgm", 6: "disp6.pgm"}, 4.0, {"two": [2, 6], "all": [0, 1, 2, 3, 5, 6, 7, 8]}),
    "art": ("art", "view", 3, {1: "disp1.png", 5: "disp5.png"}, 2.0, {"two": [1, 5], "all": [0, 1, 2, 4, 5, 6]}),
}
REF_SPACINGS = 4  # the GT disparities are per 4 view spacings (im2 <-> im6, view1 <-> view5): bad-1px in those px


def sgbm_disparity(img: np.ndarray, partner: np.ndarray, partner_right: bool, max_disp: float) -> np.ndarray:
    """OpenCV SGBM disparity (h, w) float32 px of ``img`` against ``partner`` (uint8 BGR, rectified, the partner to
    its right or left), holes (invalid matches) filled from the background side; the matcher's settings are
    OpenCV's documented ones for colour images (block 5, P1 = 8*3*25, P2 = 32*3*25, 8 paths)."""
    from workers.depth.dibr import fill_depth_holes

    n_disp = int(np.ceil(max_disp * 1.1 / 16.0)) * 16
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=n_disp, blockSize=5, P1=8 * 3 * 25, P2=32 * 3 * 25,
                                 disp12MaxDiff=1, uniquenessRatio=10, speckleWindowSize=100, speckleRange=2,
                                 mode=cv2.STEREO_SGBM_MODE_HH)
    if partner_right:
        d = sgbm.compute(img, partner).astype(np.float32) / 16.0
    else:  # mirrored, the image becomes the left one of the pair
        d = sgbm.compute(img[:, ::-1].copy(), partner[:, ::-1].copy())[:, ::-1].astype(np.float32) / 16.0
    return fill_depth_holes(np.where(d >= 0, d, np.nan).astype(np.float32))


def sgbm_dibr(images: dict[int, np.ndarray], sources: list[int], target: int, max_ref_disp: float):
    """The classic pipeline: per source view an SGBM disparity against the farthest other source within 4
    spacings, converted to the reference baseline, then :func:`synthesize_rectified` to the target
    (z-buffer, occlusion test, boundary-noise removal, background hole fill). Returns (image, disparity at the
    target in reference px, NaN where none)."""
    from workers.depth.dibr import synthesize_rectified, warp_disparity

    disps = []
    for k in sources:
        partner = max((p for p in sources if p != k and abs(p - k) <= REF_SPACINGS), key=lambda p: (abs(p - k), p))
        s = abs(partner - k)
        d = sgbm_disparity(images[k], images[partner], partner > k, max_ref_disp * s / REF_SPACINGS)
        disps.append(d * (REF_SPACINGS / s))
    shifts = [(target - k) / REF_SPACINGS for k in sources]
    synth = synthesize_rectified([images[k] for k in sources], disps, shifts)
    at_target = np.fmax.reduce([warp_disparity(d, s) for d, s in zip(disps, shifts)])
    return synth.image, at_target


def stereo_case(name: str, planes: int) -> dict:
    """Hold out the case's target view; synthesise it from two views and from all others by the sweep with each
    aggregation and by SGBM + DIBR, in the same run; PSNR on the pixels where every sweep found a depth (the
    DIBR images are complete, holes filled), bad-1px of the depth against the GT disparity warped to the target,
    wall ms. Diagnostics: GT disparity + DIBR, and the GT depth coloured by the sweep's own shading (kojima)."""
    from workers.depth.dibr import fill_depth_holes, synthesize_rectified, warp_disparity

    sub, prefix, target, gt_files, div, sets = STEREO_CASES[name]
    folder = dataset("multiview", sub)
    files = {int(p.stem[len(prefix):]): p.name for p in folder.glob(f"{prefix}*.png") if p.stem[len(prefix):].isdigit()}
    images = {k: cv2.imread(str(folder / f)) for k, f in files.items()}
    gt = {k: cv2.imread(str(folder / f), cv2.IMREAD_UNCHANGED).astype(np.float32) / div for k, f in gt_files.items()}
    gt = {k: np.where(d > 0, d, np.nan).astype(np.float32) for k, d in gt.items()}
    shifts = {k: (target - k) / REF_SPACINGS for k in gt}
    gt_target = np.fmax.reduce([warp_disparity(d, shifts[k]) for k, d in gt.items()])
    truth = images[target]
    h, w = truth.shape[:2]
    lo, hi = np.nanpercentile(np.concatenate([d.ravel() for d in gt.values()]), [0.5, 99.5]) / REF_SPACINGS
    near, far = w / (hi * 1.1), w / (lo * 0.9)
    t0 = time.perf_counter()
    gt_dibr = synthesize_rectified([images[k] for k in gt], list(gt.values()), [shifts[k] for k in gt]).image
    gt_dibr_ms = (time.perf_counter() - t0) * 1e3
    out: dict = {}
    for set_name, sources in sets.items():
        inputs, virtual = leave_one_out(files, sources, target, w, h)
        renderer = SweepRenderer(inputs, [images[k] for k in sources])
        renders, ms = {}, {}
        for agg in AGGREGATIONS:
            renderer.render(virtual, planes=8, near=near, far=far, aggregation=agg)  # compiled code loaded
            t0 = time.perf_counter()
            renders[agg] = renderer.render(virtual, planes=planes, near=near, far=far, aggregation=agg)
            ms[agg] = (time.perf_counter() - t0) * 1e3
        t0 = time.perf_counter()
        sgbm_img, sgbm_disp = sgbm_dibr(images, sources, target, hi * REF_SPACINGS)
        ms["sgbm_dibr"] = (time.perf_counter() - t0) * 1e3
        mask = np.logical_and.reduce([np.isfinite(r.depth) for r in renders.values()])
        scored = mask & np.isfinite(gt_target)
        row = {}
        for agg, r in renders.items():
            disp = REF_SPACINGS * w / r.depth  # f = w, unit baseline per spacing
            row[f"sweep_{agg}"] = {"psnr_db": psnr(r.image, truth, mask), "ssim": ssim(r.image, truth, mask),
                                   "bad1": float(np.mean(np.abs(disp[scored] - gt_target[scored]) > 1.0)),
                                   "ms": ms[agg]}
        row["sgbm_dibr"] = {"psnr_db": psnr(sgbm_img, truth, mask), "ssim": ssim(sgbm_img, truth, mask),
                            "bad1": float(np.mean(np.abs(sgbm_disp[scored] - gt_target[scored]) > 1.0)),
                            "ms": ms["sgbm_dibr"]}
        row["gt_dibr"] = {"psnr_db": psnr(gt_dibr, truth, mask), "ssim": ssim(gt_dibr, truth, mask), "bad1": 0.0,
                          "ms": gt_dibr_ms}
        # the sweep's colouring at the true depth: what a perfect depth would give this renderer
        Q, B, G = renderer._geometry(virtual)
        s_true = fill_depth_holes(gt_target).astype(np.float64) / (REF_SPACINGS * w)
        oracle, _, _ = renderer._shade(virtual, Q, B, G, s_true, False, RenderOptions(), renderers_d_bnd(renderer, virtual, s_true))
        row["gt_depth_sweep_shading"] = {"psnr_db": psnr(oracle, truth, mask), "ssim": ssim(oracle, truth, mask),
                                         "bad1": 0.0, "ms": float("nan")}
        row["scored_pixels"] = float(mask.mean())
        row["inputs"] = [files[k] for k in sources]
        out[f"{name}_{set_name}"] = row
        print(f"  stereo {name} {set_name}: " + ", ".join(f"{k} {v['psnr_db']:.2f}" for k, v in row.items()
                                                          if isinstance(v, dict)), flush=True)
    return out


def renderers_d_bnd(renderer: SweepRenderer, virtual, s_pix: np.ndarray) -> float:
    """The renderer's default D_bnd for a view whose inverse depths are s_pix (h, w) (1/m)."""
    with np.errstate(divide="ignore"):
        return renderer.auto_d_bnd(virtual, np.where(s_pix > 0, 1.0 / s_pix, np.inf))


def live_aggregation(quick: bool) -> dict:
    """The live configuration (320x240, 48 planes, 10 cameras at 640x480, the procedural scene with silhouettes)
    with each aggregation, with and without coarse-to-fine, interleaved; fps from the median wall time, CPU ms,
    the depth error against the analytic truth and the PSNR inside the object."""
    scene = default_scene()
    cams = default_arc_rig(10, width=640, height=480)
    views = render_views(scene, cams)
    hull = SweepRenderer(Rig(tuple(cams)), [v.image for v in views], backgrounds=[v.background for v in views])
    angles = arc_angles(10, 90.0)
    cam = arc_camera(float((angles[3] + angles[4]) / 2), width=320, height=240, name="live")
    gt = render(scene, cam, with_background=False)
    configs = {f"{agg}{'_c2f' if c2f else ''}": RenderOptions(planes=48, near=NEAR, far=FAR, aggregation=agg,
                                                             coarse_to_fine=c2f)
               for c2f in (True, False) for agg in AGGREGATIONS}
    reps = 7 if quick else 21
    m = interleaved({k: (lambda o=o: hull.render(cam, o)) for k, o in configs.items()}, {k: reps for k in configs},
                    warm=tuple(configs))
    out = {}
    for k, v in m.items():
        res = v["res"]
        ok = gt.silhouette & np.isfinite(res.depth)
        out[k] = {"fps": 1.0 / v["wall"], "ms": v["wall"] * 1e3, "cpu_ms": v["cpu"] * 1e3,
                  "depth_median_abs_err_mm": float(np.median(np.abs(res.depth[ok] - gt.depth[ok]))) * 1e3,
                  "psnr_db_object": psnr(res.image, gt.image, ok), "object_coverage": float(ok.sum() / gt.silhouette.sum()),
                  "load_average": os.getloadavg()[0]}
    return out


def stereo(quick: bool) -> dict:
    """The issue-20 section: Middlebury cases against SGBM + DIBR and the live configuration's speed."""
    out: dict = {"cases": {}, "notes": []}
    planes = 64 if quick else 128
    for name, case in STEREO_CASES.items():
        if dataset("multiview", case[0]) is None:
            out["notes"].append(f"Middlebury {case[0]} not found under $SWEEPCAST_DATA: skipped.")
            continue
        out["cases"].update(stereo_case(name, planes))
    out["planes"] = planes
    out["live"] = live_aggregation(quick)
    return out


def stereo_markdown(st: dict) -> str:
    rows = []
    for case, row in st["cases"].items():
        for k, v in row.items():
            if isinstance(v, dict):
                rows.append([case, k, round(v["psnr_db"], 2), round(v["ssim"], 3), round(100 * v["bad1"], 1),
                             "" if v["ms"] != v["ms"] else round(v["ms"])])
    live_rows = [[k, round(v["fps"], 1), round(v["ms"], 1), round(v["cpu_ms"], 1), round(v["depth_median_abs_err_mm"], 1),
                  round(v["psnr_db_object"], 2), round(v["object_coverage"], 3), round(v["load_average"], 1)]
                 for k, v in st["live"].items()]
    return ("### Depth choice against SGBM + DIBR (issue 20)\n\n"
            f"Held-out view synthesised from two views and from all others, {st['planes']} planes; every row of a case "
            "scored on the same pixels (where each sweep found a depth; DIBR images hole-filled). bad-1px: share of "
            "those pixels with a GT disparity (GT maps forward-warped to the target) where the depth's disparity, in "
            "px per 4 view spacings, is off by more than 1. sweep_none: winner-take-all per pixel (the pruned fast "
            "path); sweep_window: variance over a 5x5 window; sweep_sgm: that as a capped RMS deviation plus 8-path "
            "semi-global aggregation; all with sub-plane parabola refinement except none. sgbm_dibr: "
            "cv2.StereoSGBM (MODE_HH) per source view + workers/depth/dibr.py; gt_dibr: GT disparity + DIBR; "
            "gt_depth_sweep_shading: the GT depth coloured by the sweep's kojima shading (what a perfect depth gives "
            "this renderer).\n\n"
            + md_table(["case", "pipeline", "PSNR", "SSIM", "bad-1px %", "ms"], rows)
            + "\n\n### Live configuration by aggregation (320x240, 48 planes, 10 cameras, hull)\n\n"
              "Interleaved repeats, medians. _c2f: the aggregation at half resolution, then the pruned search "
              "within +-2 planes at full resolution.\n\n"
            + md_table(["config", "fps", "ms", "CPU ms", "depth median err (mm)", "PSNR object", "covered", "load avg"],
                       live_rows)
            + ("\n\n" + "\n".join(f"- {n}" for n in st["notes"]) if st["notes"] else ""))

# --- report -------------------------------------------------------------------------------------
def markdown(results: dict, notes: list[str]) -> str:
    parts = []
    q = results["quality"]
    rows = []
    for scene_name, per in q.items():
        for m in METHODS:
            if m in per:
                rows.append([scene_name, m, round(per[m]["psnr_db"], 2), round(per[m]["ssim"], 3)])
    parts.append("### Quality (PSNR dB / SSIM, higher is better)\n\n" + md_table(["scene", "method", "PSNR", "SSIM"], rows))
    t = results.get("temporal")
    if t:
        rows = [[m, round(t[m]["max_jump"], 2), round(t[m]["max_excess_jump"], 2), round(t[m]["blur_hf_ratio"], 3),
                 round(t[m]["psnr_db"], 2)] for m in METHODS]
        parts.append(
            f"### Moving virtual camera ({t['truth']['frames']} frames, {t['truth']['step_deg']} deg steps across 4 "
            f"camera switches; the truth's own largest frame-to-frame change is {t['truth']['max_jump']:.2f})\n\n"
            + md_table(["method", "max jump", "max jump beyond truth", "blur (HF energy / truth)", "PSNR"], rows))
    s = results.get("speed")
    if s:
        rows = [[k, round(v["fps"], 2), round(v["msamples_per_s"], 1), round(v["reference_msamples_per_s"], 1),
                 round(v["speedup_vs_reference"], 1), round(v["speedup_cpu_time_vs_reference"], 1),
                 round(v["depth_agreement"], 4), round(v["load_average"], 1)]
                for k, v in s.items() if not k.startswith(("live", "search_"))]
        parts.append("### Speed, full sweep (10 cameras 640x480, no hull, no shortcuts; equal output: OpenCV's 1/32 px "
                     "sampling)\n\nspeedup: the reference's wall time over the sweep's, medians of interleaved runs; "
                     "CPU-time speedup: the reference's process CPU time over the whole render's (both threads "
                     "counted). Depth agreement: share of pixels seen by all cameras where both choose the same plane."
                     "\n\n" + md_table(["config", "fps", "Msamples/s", "reference Msamples/s", "speedup (sweep)",
                                         "speedup (CPU time)", "depth agreement", "load avg"], rows))
        live_rows = [[k, round(v["fps"], 1), round(v["render_cpu_s"] * 1e3, 1),
                 " / ".join(f"{n[:-3]} {t:.1f}" for n, t in v["stages_ms"].items() if n not in ("total_ms", "prepare_ms")),
                 round(v["speedup_vs_reference"], 1), round(v["depth_median_abs_err_m"] * 1000, 1),
                 round(v["depth_within_2_planes"], 3), round(v["object_coverage"], 3), round(v["psnr_db_kojima_object"], 2),
                 round(v["load_average"], 1)]
                for k, v in s.items() if k.startswith("live_320")]
        lp = s.get("search_lanes_vs_pixel")
        if lp:
            rows = [[k, round(v["lanes_ms"], 1), round(v["pixel_ms"], 1), round(v["speedup"], 2), v["same_choice"]]
                    for k, v in lp.items()]
            parts.append("### Depth search: 16-lane vector code against the plain-numba search\n\nThe variance search "
                         "alone on the same plane windows, medians of 7 interleaved runs; the plain search is pixel by "
                         "pixel with the same exact pruning and plane order. The lane code (hand-written LLVM IR) "
                         "stays only while it is at least 1.3x faster on the full sweep.\n\n"
                         + md_table(["config", "lanes ms", "plain numba ms", "speedup", "same plane everywhere"], rows))
        extras = s.get("live_per_frame_extras", {})
        parts.append("### Live configuration (320x240, 48 planes, 10 cameras; speedup: whole render against the "
                     "reference's full 48-plane sweep)\n\nfps from the median wall time per render; CPU ms: process "
                     "CPU time per render (both threads); stages: median wall ms. Per new frame set: set_frames "
                     f"(10 silhouettes + packing) {extras.get('set_frames_10_cameras_ms', float('nan')):.1f} ms; "
                     f"JPEG encode of a 320x240 view {extras.get('jpeg_encode_320x240_ms', float('nan')):.2f} ms.\n\n"
                     + md_table(["config", "fps", "CPU ms", "stages (ms)", "speedup", "depth median err (mm)",
                                 "within 2 planes", "object covered", "PSNR kojima", "load avg"], live_rows))
    if results.get("stereo"):
        parts.append(stereo_markdown(results["stereo"]))
    parts.append("\n".join(f"- {n}" for n in notes))
    return "\n\n".join(parts)


def quality_notes() -> list[str]:
    return [f"Procedural rig: 10 cameras on a 90 deg arc, per-camera colour gains within +-{GAIN_SPREAD:.0%} "
            "(real cameras differ in exposure/white balance); truth rendered with gain 1; scored inside the object.",
            "kojima uses the renderer's default D_bnd: suggest_d_bnd(camera spacing seen from the surface, 0.5); "
            "ulrK blends K cameras.",
            "The depth (one sweep) is shared by all methods of a row; only the colour weighting differs."]


MIDDLEBURY_NOTES = [
    "Middlebury rectified sets: depth range from the ground-truth disparity's 0.5-99.5 percentiles; scored on "
    "pixels where >= 2 input views agree on a depth (coverage in the JSON). For scale, NOTES.md: forward-warp DIBR "
    "with ground-truth disparity, Teddy im2+im6 -> im4, 29.3 dB; copying the nearest view 16.9 dB.",
    "templeSparseRing: silhouettes by thresholding against the black background (70 levels, above the dark "
    "cloth); the held-out view's silhouette is the scoring mask.",
]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a short run (fewer views, frames and configurations)")
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--skip-data", action="store_true", help="skip the Middlebury sets")
    ap.add_argument("--skip-stereo", action="store_true", help="skip the comparison with SGBM + DIBR")
    ap.add_argument("--stereo-only", action="store_true",
                    help="run only the comparison with SGBM + DIBR; keep the other sections of the previous run (marked)")
    ap.add_argument("--speed-only", action="store_true",
                    help="measure speed only; keep the quality and temporal results of the previous run (marked)")
    args = ap.parse_args()
    if args.stereo_only:
        return stereo_only(args.quick)
    if args.speed_only:
        return speed_only(args.quick)
    load0 = os.getloadavg()[0]
    results: dict = {"quality": {}, "temporal": {}, "speed": {}}
    notes = quality_notes()
    size = (320, 240) if args.quick else (640, 480)
    t0 = time.perf_counter()
    scene, renderer = procedural_capture(size)
    results["quality"]["procedural"] = procedural_quality(scene, renderer, size, args.quick)
    print(f"procedural quality done ({time.perf_counter() - t0:.0f} s)", flush=True)
    results["temporal"] = temporal(scene, renderer, (320, 240), args.quick)
    print(f"temporal done ({time.perf_counter() - t0:.0f} s)", flush=True)
    planes = 64 if args.quick else 128
    if not args.skip_data:
        teddy = dataset("multiview", "teddy")
        if teddy is None:
            notes.append("Middlebury Teddy not found under $SWEEPCAST_DATA: skipped.")
        else:
            sets = {"im3_im5": [3, 5], "im2_im6": [2, 6], "all": [0, 1, 2, 3, 5, 6, 7, 8]}
            for k, v in rectified_quality(teddy, "im", 4, sets, "disp2.pgm", 4.0, 4, planes).items():
                results["quality"][f"teddy_{k}"] = v
            print(f"teddy done ({time.perf_counter() - t0:.0f} s)", flush=True)
        art = dataset("multiview", "art")
        if art is None:
            notes.append("Middlebury Art not found under $SWEEPCAST_DATA: skipped.")
        else:
            sets = {"view2_view4": [2, 4], "view1_view5": [1, 5], "all": [0, 1, 2, 4, 5, 6]}
            for k, v in rectified_quality(art, "view", 3, sets, "disp1.png", 2.0, 4, planes).items():
                results["quality"][f"art_{k}"] = v
            print(f"art done ({time.perf_counter() - t0:.0f} s)", flush=True)
        temple = dataset("multiview", "temple")
        if temple is None:
            notes.append("templeSparseRing not found under $SWEEPCAST_DATA: skipped.")
        else:
            for k, v in temple_quality(temple, args.quick, planes).items():
                results["quality"][f"temple_{k}"] = v
            print(f"temple done ({time.perf_counter() - t0:.0f} s)", flush=True)
        notes += MIDDLEBURY_NOTES
    if not args.skip_stereo:
        results["stereo"] = stereo(args.quick)
        print(f"stereo done ({time.perf_counter() - t0:.0f} s)", flush=True)
    if not args.skip_speed:
        results["speed"] = speed(args.quick)
        print(f"speed done ({time.perf_counter() - t0:.0f} s)", flush=True)
    load1 = os.getloadavg()[0]
    results["load_average"] = {"start": load0, "end": load1}
    notes.append(load_note(load0, load1))
    publish("sweep", results, markdown(results, notes))
    return 0


def load_note(load0: float, load1: float) -> str:
    """The machine's load around the speed section: the start figure tells whether anything else was
    running (the end figure includes this benchmark's own threads)."""
    threads = numba.get_num_threads()
    note = (f"1-minute load average {load0:.1f} at the start and {load1:.1f} at the end on {os.cpu_count()} cores "
            f"(the end figure includes this benchmark's own {threads} threads)")
    if load0 > 0.5:
        note += (": other work was running, and speed figures under CPU contention are not representative; the "
                 "renderer and the reference were measured in the same run, interleaved, and the sweep loses its "
                 "second core first, so the wall-clock speedup understates the quiet-machine figure")
    return note + (f". The sweep runs on {threads} threads and the reference mostly on one; the CPU-time speedup is "
                   "the work ratio, nearly independent of the load.")


def speed_only(quick: bool) -> int:
    """Re-measure the speed section; the quality and temporal sections (and their notes) come from the
    previous results file, whose date is said in the notes."""
    previous = json.loads((Path(__file__).resolve().parent / "results" / "sweep.json").read_text())
    origin = previous.get("quality_from_run", previous["meta"])  # a speed-only run keeps the first origin
    load0 = os.getloadavg()[0]
    results = {"quality": previous["quality"], "temporal": previous["temporal"], "quality_from_run": origin,
               "speed": speed(quick)}
    load1 = os.getloadavg()[0]
    results["load_average"] = {"start": load0, "end": load1}
    notes = quality_notes() + MIDDLEBURY_NOTES + [
        f"Speed measured in this run; the quality and temporal tables are from the run of {origin['date']} "
        f"(`{origin['command']}`), kept unchanged.",
        load_note(load0, load1)]
    publish("sweep", results, markdown(results, notes))
    return 0


def stereo_only(quick: bool) -> int:
    """Run the comparison with SGBM + DIBR; every other section comes from the previous results file, whose
    date is said in the notes."""
    previous = json.loads((Path(__file__).resolve().parent / "results" / "sweep.json").read_text())
    origin = previous.get("quality_from_run", previous["meta"])
    load0 = os.getloadavg()[0]
    results = {k: v for k, v in previous.items() if k != "meta"}
    results["quality_from_run"] = origin
    results["stereo"] = stereo(quick)
    load1 = os.getloadavg()[0]
    results["load_average"] = {"start": load0, "end": load1}
    notes = quality_notes() + MIDDLEBURY_NOTES + [
        f"The comparison with SGBM + DIBR was measured in this run; the other tables are from the run of "
        f"{origin['date']} (`{origin['command']}`), kept unchanged.", load_note(load0, load1)]
    publish("sweep", results, markdown(results, notes))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
