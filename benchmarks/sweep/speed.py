"""Sweep benchmark, question 2: how fast is the fused kernel.

10 cameras at 640x480, virtual 640x480 / 320x240, 32/64/128 planes, the fused kernel against the
straightforward per-plane cv2.warpPerspective + numpy variance, in the same run (interleaved repeats, medians;
wall and CPU time); the live configuration (320x240, 48 planes) with and without visual hull and coarse-to-fine,
with the depth error against the truth beside each, and the per-frame extras of a stream (set_frames, JPEG
encode).

    python -m benchmarks.sweep --only speed [--quick]
"""
from __future__ import annotations

import os

import cv2
import numpy as np

from benchmarks._report import md_table
from benchmarks.sweep.common import FAR, NEAR, interleaved
from workers.synth import arc_angles, arc_camera, default_arc_rig, default_scene, render, render_views
from workers.common.imagemetrics import psnr
from workers.sweep.reference import reference_sweep
from workers.sweep.renderer import RenderOptions, RenderResult, SweepRenderer
from workers.sweep.rig import Rig

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
        Q, B, _ = r.geometry(cam)
        lo, hi = r.search_window(Q, B, h, w, s_planes, use_hull)
        m = interleaved({name: (lambda lanes=lanes: r.sweep(Q, B, cam.center, s_planes, use_hull, opts, lo, hi, lanes))
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



def markdown_parts(results: dict) -> list[str]:
    """The speed tables of the RESULTS section (none without the speed results)."""
    parts: list[str] = []
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
    return parts
