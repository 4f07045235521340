"""The GPU depth search against the CPU's on a procedural capture: prints one JSON line.

    python -m tests.sweep.gpu_check --width 40 --height 30 --planes 8     (NUMBA_ENABLE_CUDASIM=1 on a CPU)

For each option set, both renderers render the same virtual view; the report gives the fraction of
pixels whose plane agrees (within one plane: rounding may
turn a near-tie either way), the PSNR of the GPU's image against the CPU's,
the median and 99th percentile of the cost sums' relative difference, and the GPU's device.
"""
from __future__ import annotations

import argparse
import json

import numpy as np

from workers.synth import arc_angles, arc_camera, default_arc_rig, default_scene, render_views
from workers.common.imagemetrics import psnr
from workers.sweep.renderer import RenderOptions, SweepRenderer
from workers.sweep.rig import Rig

CASES = {
    "none": dict(aggregation="none", visual_hull=False),
    "window": dict(aggregation="window", window=2, visual_hull=False),
    "sgm": dict(aggregation="sgm", sgm_directions=4, visual_hull=False),
    "window_fill": dict(aggregation="window", window=2, visual_hull=False, occlusions="fill"),
    "window_hull_c2f": dict(aggregation="window", window=1, visual_hull=True, coarse_to_fine=True),
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--width", type=int, default=40)
    ap.add_argument("--height", type=int, default=30)
    ap.add_argument("--cameras", type=int, default=4)
    ap.add_argument("--planes", type=int, default=8)
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated names of CASES")
    args = ap.parse_args()
    cams = default_arc_rig(args.cameras, arc_deg=60.0, width=args.width, height=args.height)
    views = render_views(default_scene(), cams)
    rig = Rig(tuple(cams))
    images = [v.image for v in views]
    backgrounds = [v.background for v in views]
    cpu = SweepRenderer(rig, images, backgrounds=backgrounds, device="cpu")
    gpu = SweepRenderer(rig, images, backgrounds=backgrounds, device="cuda")
    a = arc_angles(args.cameras, 60.0)
    virtual = arc_camera(float((a[1] + a[2]) / 2), width=args.width, height=args.height, name="virtual")
    report: dict = {"device": gpu.device, "cases": {}}
    for name in args.cases.split(","):
        opts = CASES[name]
        opt = RenderOptions(planes=args.planes, near=1.6, far=3.6, **opts)
        rc = cpu.render(virtual, opt)
        rg = gpu.render(virtual, opt)
        both = (rc.plane_index >= 0) & (rg.plane_index >= 0)
        same_found = float(np.mean((rc.plane_index >= 0) == (rg.plane_index >= 0)))
        near = float(np.mean(np.abs(rc.plane_index[both] - rg.plane_index[both]) <= 1)) if both.any() else 1.0
        exact = float(np.mean(rc.plane_index[both] == rg.plane_index[both])) if both.any() else 1.0
        report["cases"][name] = {"same_filled": float(np.mean(rc.filled == rg.filled)), "same_found": same_found, "within_one_plane": near, "same_plane": exact,
                                 "psnr_gpu_vs_cpu": float(psnr(rc.image, rg.image)),
                                 "pixels_with_depth": float(np.mean(rc.plane_index >= 0))}
    Q, B, _ = cpu.geometry(virtual)
    s_planes = 1.0 / cpu.depth_planes(virtual, args.planes, 1.6, 3.6)
    lo = np.zeros((args.height, args.width), np.int32)
    hi = np.full((args.height, args.width), args.planes - 1, np.int32)
    ssd_c, votes_c = cpu._volume(Q, B, virtual.center, s_planes, False, RenderOptions(), lo, hi)
    ssd_g, votes_g = gpu._gpu.cost_sums(Q, B, s_planes, False, 2, 6, lo, hi)
    report["votes_equal"] = float(np.mean(votes_c == votes_g))
    agree = (votes_c == votes_g) & (votes_c > 0)
    scale = np.maximum(ssd_c[agree], 100.0)  # colour levels squared: relative above 10 levels of deviation
    rel = np.abs(ssd_c[agree] - ssd_g[agree]) / scale if agree.any() else np.zeros(1)
    report["ssd_rel_diff_median"] = float(np.median(rel))
    report["ssd_rel_diff_p99"] = float(np.percentile(rel, 99))
    print(json.dumps(report))


if __name__ == "__main__":
    main()
