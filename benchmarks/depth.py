"""Depth post-filter benchmark (Lee, Yang & Oh): depth error and view synthesis on Middlebury data.

For Teddy and Art: the ground-truth (GT) disparity is coded as 8-bit inverse-depth levels,
downsampled (area average) by 2 and 4, JPEG-compressed at a few qualities, upsampled back
(nearest or bilinear, as a decoder would), and post-filtered by each method. Measured:
(a) depth error against the GT (MAE and bad-pixel rate, > 1 px disparity) overall and in a band
around the GT depth edges, on the views that have GT; (b) the middle view synthesised (DIBR) from
two views with each method's depth, against the real middle view: PSNR and SSIM overall and in the
edge band; (c) throughput of x2 upsampling + modified dilation + morphology on a 1920x1088 8-bit
frame, with ``cv2.dilate`` alone timed in the same run as the reference.

Depth for views without GT (Teddy im3/im5/im4, Art view2/view4/view3): GT exists only for Teddy
im2/im6 and Art view1/view5, so the depth of any other view is derived by forward-warping both GT
maps to it (z-buffered, rectified geometry, equal spacing), keeping the nearer surface, and
filling what neither GT view sees from the background side. This "derived GT" is exact wherever
one GT view sees the surface; it is used as the source depth for the im3+im5 / view2+view4 pairs
and to find the depth edges of the middle (target) view. Unknown GT pixels (value 0) are filled
the same way before coding, since a codec needs a complete map; errors are measured only where GT
is known.

Run: ``python benchmarks/depth.py [--quick]`` from the repository root.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import md_table, publish  # noqa: E402
from workers.common.datasets import dataset  # noqa: E402
from workers.depth import dibr, metrics  # noqa: E402
from workers.depth.levels import disparity_to_levels, levels_to_disparity  # noqa: E402
from workers.depth.methods import FilterOptions, apply_method  # noqa: E402
from workers.depth.pipeline import FramePipeline  # noqa: E402
from workers.depth.upsample import upsample  # noqa: E402

PAPER_METHODS = ["none", "dilation", "modified", "modified_morph"]
ALL_METHODS = PAPER_METHODS + ["wmf"]
# ablations of the paper's method: label -> (method, FilterOptions overrides)
ABLATIONS = {
    "modified_morph[otsu]": ("modified_morph", {"rule": "otsu"}),
    "modified_morph[close-open]": ("modified_morph", {"morph_order": "close-open"}),
    "modified_morph[min_contrast=8]": ("modified_morph", {"min_contrast": 8}),
    "modified[otsu]": ("modified", {"rule": "otsu"}),
}
EDGE_JUMP_PX = 2.0  # a 3x3 disparity span above this (reference-baseline pixels) is a depth edge
EDGE_RADIUS = 3
BAD_PX = 1.0


@dataclass(frozen=True)
class Sequence:
    name: str
    folder: str
    image: str  # file name pattern of view k
    gt: dict[int, tuple[str, float]]  # view -> (file, divisor giving disparity in pixels)
    spacing: int  # view spacings between the two GT views (their disparity's reference baseline)
    pairs: tuple[tuple[int, int, int], ...]  # (left, right, target)


SEQUENCES = [
    Sequence("teddy", "teddy", "im{}.png", {2: ("disp2.pgm", 4.0), 6: ("disp6.pgm", 4.0)}, 4,
             ((2, 6, 4), (3, 5, 4))),
    Sequence("art", "art", "view{}.png", {1: ("disp1.png", 2.0), 5: ("disp5.png", 2.0)}, 4,
             ((1, 5, 3), (2, 4, 3))),
]


@dataclass
class SceneData:
    seq: Sequence
    images: dict[int, np.ndarray]
    gt: dict[int, np.ndarray]  # views with real GT: disparity px, NaN unknown
    depth: dict[int, np.ndarray]  # every view used: GT or derived GT, NaN unknown
    d_range: tuple[float, float]


def load_scene(seq: Sequence, root: Path) -> SceneData:
    views = sorted({v for pair in seq.pairs for v in pair})
    images = {k: cv2.imread(str(root / seq.image.format(k)), cv2.IMREAD_COLOR) for k in views}
    gt = {}
    for k, (name, div) in seq.gt.items():
        raw = cv2.imread(str(root / name), cv2.IMREAD_UNCHANGED).astype(np.float32)
        gt[k] = np.where(raw > 0, raw / div, np.nan).astype(np.float32)
    depth = {k: gt[k] if k in gt else derive_depth(gt, k, seq.spacing) for k in views}
    valid = np.concatenate([d[np.isfinite(d)] for d in gt.values()])
    return SceneData(seq, images, gt, depth, (float(valid.min()), float(valid.max())))


def derive_depth(gt: dict[int, np.ndarray], view: int, spacing: int) -> np.ndarray:
    """Disparity of ``view`` by warping every GT map to it and keeping the nearer surface."""
    warped = np.stack([dibr.warp_disparity(d, (view - k) / spacing) for k, d in gt.items()])
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(warped).any(0), np.nanmax(np.nan_to_num(warped, nan=-np.inf), 0), np.nan)


def jpeg(levels: np.ndarray, quality: int | None) -> np.ndarray:
    if quality is None:
        return levels
    ok, buf = cv2.imencode(".jpg", levels, [cv2.IMWRITE_JPEG_QUALITY, quality])
    return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)


def options_for(factor: int, base: FilterOptions) -> FilterOptions:
    """Windows that cover the blur of an upsampling by ``factor`` (3 and 9 pixels for x2)."""
    return replace(base, window=factor + 1, guide_window=2 * factor + 5)


def decode_chain(levels: np.ndarray, factor: int, quality: int | None, upsampler: str) -> np.ndarray:
    h, w = levels.shape
    low = cv2.resize(levels, (round(w / factor), round(h / factor)), interpolation=cv2.INTER_AREA)
    return upsample(jpeg(low, quality), size=(w, h), mode=upsampler)


def edge_band_of(disp: np.ndarray) -> np.ndarray:
    return metrics.edge_band(np.nan_to_num(disp, nan=0.0), EDGE_JUMP_PX, EDGE_RADIUS, np.isfinite(disp))


def run_condition(
    scene: SceneData, factor: int, quality: int | None, upsampler: str, variants: dict[str, tuple[str, dict]],
    base: FilterOptions,
) -> dict:
    """Every variant (label -> (method, option overrides)) on one coding condition of one scene:
    depth errors and synthesis scores."""
    lo, hi = scene.d_range
    zn, zf = 1.0 / hi, 1.0 / lo  # levels linear in disparity: MPEG inverse depth with f*B = 1
    opts = options_for(factor, base)
    methods = list(variants)
    disp: dict[str, dict[int, np.ndarray]] = {m: {} for m in methods}
    seconds = {m: 0.0 for m in methods}
    for k, d in scene.depth.items():
        levels = disparity_to_levels(dibr.fill_depth_holes(d), zn, zf, 1.0)
        decoded = decode_chain(levels, factor, quality, upsampler)
        for m, (method, overrides) in variants.items():
            t0 = time.perf_counter()
            out = apply_method(decoded, method, scene.images[k], replace(opts, **overrides))
            seconds[m] += time.perf_counter() - t0
            disp[m][k] = levels_to_disparity(out, zn, zf, 1.0)
    result = {"depth": {}, "synthesis": {}, "filter_seconds": seconds}
    for m in methods:
        result["depth"][m] = depth_scores(scene, disp[m])
        result["synthesis"][m] = synthesis_scores(scene, disp[m])
    return result


def depth_scores(scene: SceneData, disp: dict[int, np.ndarray]) -> dict[str, float]:
    rows = []
    for k, truth in scene.gt.items():
        valid = np.isfinite(truth)
        band = edge_band_of(truth)
        t = np.nan_to_num(truth)
        rows.append((metrics.depth_errors(disp[k], t, valid, BAD_PX), metrics.depth_errors(disp[k], t, valid, BAD_PX, band)))
    return {
        "mae": float(np.mean([a["mae"] for a, _ in rows])),
        "bad_rate": float(np.mean([a["bad_rate"] for a, _ in rows])),
        "edge_mae": float(np.mean([b["mae"] for _, b in rows])),
        "edge_bad_rate": float(np.mean([b["bad_rate"] for _, b in rows])),
    }


def synthesis_one(scene: SceneData, disp: dict[int, np.ndarray], left: int, right: int, target: int) -> dict[str, float]:
    """Synthesise ``target`` from ``left`` + ``right`` with the given disparities; scores vs the real view."""
    s = scene.seq.spacing
    syn = dibr.synthesize_rectified(
        [scene.images[left], scene.images[right]], [disp[left], disp[right]],
        [(target - left) / s, (target - right) / s],
    )
    real = scene.images[target]
    band = edge_band_of(scene.depth[target])
    return {
        "psnr_db": metrics.psnr(syn.image, real), "edge_psnr_db": metrics.psnr(syn.image, real, band),
        "ssim": metrics.ssim(syn.image, real), "edge_ssim": metrics.ssim(syn.image, real, band),
        "hole_rate": float(syn.holes.mean()),
    }


def synthesis_scores(scene: SceneData, disp: dict[int, np.ndarray]) -> dict[str, dict[str, float]]:
    return {f"{l}+{r}->{t}": synthesis_one(scene, disp, l, r, t) for l, r, t in scene.seq.pairs}


def anchors(scene: SceneData) -> dict[str, dict[str, dict[str, float]]]:
    """Synthesis from uncoded depth with the same renderer: the GT/derived-GT disparity itself (unknown
    pixels not warped), the same with unknown pixels filled, and that filled map dilated 3x3 (to
    show how much this renderer gains from foreground fattening even without coding)."""
    filled = {k: dibr.fill_depth_holes(d) for k, d in scene.depth.items()}
    kinds = {
        "gt": scene.depth,
        "gt_filled": filled,
        "gt_filled_dilated3": {k: cv2.dilate(d, np.ones((3, 3), np.uint8)) for k, d in filled.items()},
    }
    out: dict[str, dict[str, dict[str, float]]] = {}
    for left, right, target in scene.seq.pairs:
        key = f"{left}+{right}->{target}"
        out[key] = {kind: synthesis_one(scene, depth, left, right, target) for kind, depth in kinds.items()}
        out[key]["nearest_source_view"] = {"psnr_db": metrics.psnr(scene.images[left], scene.images[target])}
    return out


def synthetic_low_res_frame() -> np.ndarray:
    """A 960x544 decoded depth frame: nearer discs over a background, JPEG-coded."""
    rng = np.random.default_rng(0)
    low = np.full((544, 960), 60, np.uint8)
    for _ in range(40):
        c = (int(rng.integers(0, 960)), int(rng.integers(0, 544)))
        cv2.circle(low, c, int(rng.integers(10, 120)), int(rng.integers(80, 250)), -1)
    return jpeg(low, 60)


def _timed(fn, reps: int) -> tuple[float, float]:
    """Median wall and thread-CPU seconds of ``fn()`` over ``reps`` calls."""
    wall, cpu = [], []
    for _ in range(reps):
        w0, c0 = time.perf_counter(), time.thread_time()
        fn()
        cpu.append(time.thread_time() - c0)
        wall.append(time.perf_counter() - w0)
    return statistics.median(wall), statistics.median(cpu)


def _two_workers(make, frames: int) -> float:
    """Frames/s of two threads (one per core) each running ``make()()`` on ``frames`` frames."""
    workers = [make() for _ in range(2)]
    for w in workers:
        w()  # warm up
    barrier = threading.Barrier(3)

    def loop(fn) -> None:
        barrier.wait()
        for _ in range(frames):
            fn()

    threads = [threading.Thread(target=loop, args=(w,)) for w in workers]
    for t in threads:
        t.start()
    barrier.wait()
    t0 = time.perf_counter()
    for t in threads:
        t.join()
    return 2 * frames / (time.perf_counter() - t0)


def throughput(reps: int) -> dict[str, float]:
    """1920x1088 8-bit frames: x2 nearest upsampling + modified dilation + closing (3x3) with the
    engine's FramePipeline, and ``cv2.dilate`` 3x3 alone as the reference, measured the same ways
    in the same run: one thread (median wall and CPU time per frame) and two worker threads, one per
    core, each with its own pipeline (OpenCV's own threading off). The 2-core figure is the target."""
    cv2.setNumThreads(1)
    low = synthetic_low_res_frame()
    full = upsample(low, scale=2)
    kernel = np.ones((3, 3), np.uint8)

    def make_pipeline():
        pipe = FramePipeline(low.shape, (1920, 1088), "modified_morph", "nearest", FilterOptions())
        return lambda: pipe(low)

    def make_dilate():
        dst = np.empty_like(full)
        return lambda: cv2.dilate(full, kernel, dst=dst)

    pipe_wall, pipe_cpu = _timed(make_pipeline(), reps)
    dil_wall, dil_cpu = _timed(make_dilate(), reps)
    fps2 = _two_workers(make_pipeline, reps)
    dil_fps2 = _two_workers(make_dilate, reps)
    return {
        "fps_1080p": fps2, "fps_1080p_one_thread": 1.0 / pipe_wall, "cpu_ms_per_frame": 1000 * pipe_cpu,
        "ms_per_frame_one_thread": 1000 * pipe_wall, "dilate_only_fps": dil_fps2,
        "dilate_only_fps_one_thread": 1.0 / dil_wall, "dilate_only_cpu_ms": 1000 * dil_cpu, "reps": reps,
        "cores": os.cpu_count(), "load_average_1min": os.getloadavg()[0],
    }


def mean_over(conditions: list[dict], section: str, labels: list[str], key: str) -> dict[str, float]:
    """Average of a score per variant over conditions (and, for synthesis, over the pairs)."""
    out = {}
    for m in labels:
        vals = []
        for c in conditions:
            node = c[section][m]
            vals += [p[key] for p in node.values()] if section == "synthesis" else [node[key]]
        out[m] = float(np.mean(vals))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="x2, JPEG 70, nearest upsampling, no ablations")
    args = ap.parse_args(argv)
    roots = {s.name: dataset("multiview", s.folder) for s in SEQUENCES}
    missing = [n for n, r in roots.items() if r is None]
    if missing:
        print(f"skipping the depth benchmark: multiview data for {', '.join(missing)} not found "
              "(set $SWEEPCAST_DATA to the data folder)")
        return 0
    grid = {
        "factors": [2] if args.quick else [2, 4],
        "qualities": [70] if args.quick else [None, 90, 70, 50],
        "upsamplers": ["nearest"] if args.quick else ["nearest", "bilinear"],
    }
    variants = {m: (m, {}) for m in ALL_METHODS}
    if not args.quick:
        variants.update(ABLATIONS)
    base = FilterOptions()
    scenes = [load_scene(s, roots[s.name]) for s in SEQUENCES]
    conditions = []
    for scene in scenes:
        for up in grid["upsamplers"]:
            for f in grid["factors"]:
                for q in grid["qualities"]:
                    t0 = time.perf_counter()
                    res = run_condition(scene, f, q, up, variants, base)
                    res.update(sequence=scene.seq.name, upsampler=up, factor=f,
                               jpeg_quality=q if q is not None else "lossless")
                    conditions.append(res)
                    print(f"{scene.seq.name} {up} x{f} q={q}: {time.perf_counter() - t0:.1f}s", file=sys.stderr)
    results = summarise(conditions, list(variants), scenes, grid, base)
    results["throughput"] = throughput(30 if args.quick else 300)
    text = markdown(results, grid)
    publish("depth", results, text)
    print(text)
    return 0


def summarise(conditions: list[dict], labels: list[str], scenes: list[SceneData], grid: dict, base: FilterOptions) -> dict:
    results: dict = {
        "config": {
            **{k: [("lossless" if v is None else v) for v in vals] for k, vals in grid.items()},
            "downsampling": "area", "levels": "8-bit, linear in disparity (MPEG inverse depth)",
            "edge_jump_px": EDGE_JUMP_PX, "edge_radius_px": EDGE_RADIUS, "bad_pixel_threshold_px": BAD_PX,
            "window": "factor + 1", "guide_window": "2 * factor + 5", "filter_options": base.__dict__,
            "variants": {k: {"method": m, **o} for k, (m, o) in (ABLATIONS | {x: (x, {}) for x in ALL_METHODS}).items()
                         if k in labels},
        },
        "anchors": {s.seq.name: anchors(s) for s in scenes},
        "synthesis": {}, "depth": {}, "by_upsampler": {}, "by_condition": {}, "conditions": conditions,
    }
    for key in ("psnr_db", "edge_psnr_db", "ssim", "edge_ssim"):
        for m, v in mean_over(conditions, "synthesis", labels, key).items():
            results["synthesis"].setdefault(m, {})[key] = v
    for key in ("mae", "bad_rate", "edge_mae", "edge_bad_rate"):
        for m, v in mean_over(conditions, "depth", labels, key).items():
            results["depth"].setdefault(m, {})[key] = v
    for up in grid["upsamplers"]:
        sub = [c for c in conditions if c["upsampler"] == up]
        psnr = mean_over(sub, "synthesis", labels, "psnr_db")
        edge = mean_over(sub, "synthesis", labels, "edge_psnr_db")
        results["by_upsampler"][up] = {
            "psnr_db": psnr, "edge_psnr_db": edge,
            "per_sequence_psnr_db": {
                s.seq.name: mean_over([c for c in sub if c["sequence"] == s.seq.name], "synthesis", labels, "psnr_db")
                for s in scenes
            },
            "paper_order_holds_psnr": ordering(psnr), "paper_order_holds_edge_psnr": ordering(edge),
        }
        per = results["by_upsampler"][up]["per_sequence_psnr_db"]
        results["by_upsampler"][up]["paper_order_holds_per_sequence"] = {k: ordering(v) for k, v in per.items()}
    for f in grid["factors"]:
        for q in grid["qualities"]:
            qn = "lossless" if q is None else q
            sub = [c for c in conditions if c["factor"] == f and c["jpeg_quality"] == qn]
            results["by_condition"][f"x{f}/q{qn}"] = mean_over(sub, "synthesis", labels, "psnr_db")
    results["paper_order_holds"] = ordering({m: results["synthesis"][m]["psnr_db"] for m in labels})
    results["paper_order_holds_edge"] = ordering({m: results["synthesis"][m]["edge_psnr_db"] for m in labels})
    return results


def ordering(score: dict[str, float]) -> bool:
    """The paper's claim: modified + morphology >= modified >= dilation > none."""
    return score["modified_morph"] >= score["modified"] >= score["dilation"] > score["none"]


def markdown(results: dict, grid: dict) -> str:
    methods = ALL_METHODS
    qs = ", ".join("lossless" if q is None else str(q) for q in grid["qualities"])
    parts = [
        "Middlebury Teddy (im4 from im2+im6 and im3+im5) and Art (view3 from view1+view5 and view2+view4). "
        "GT disparity as 8-bit inverse-depth levels, downsampled x"
        + ", x".join(map(str, grid["factors"])) + f" (area), JPEG quality {qs}, upsampled "
        + " / ".join(grid["upsamplers"]) + "; filter window = factor + 1, closing 3x3; wmf window 2 x factor + 5. "
        "Views without GT (im3, im5, view2, view4, and the targets' edge bands) use GT warped from the two GT "
        "views. Renderer: z-buffered forward warp of depth, crack filling, backward texture sampling, "
        "1-pixel boundary-noise removal, two-view blending, background hole filling. Edge band: pixels within "
        f"{EDGE_RADIUS} px of a GT disparity jump > {EDGE_JUMP_PX} px.",
    ]
    for up in grid["upsamplers"]:
        r = results["by_upsampler"][up]
        rows = [[seq, per["none"]] + [per[m] - per["none"] for m in methods[1:]] for seq, per in r["per_sequence_psnr_db"].items()]
        avg = r["psnr_db"]
        rows.append(["AVG.", avg["none"]] + [avg[m] - avg["none"] for m in methods[1:]])
        parts.append(
            f"**Table I analogue ({up} upsampling)**: synthesised-view PSNR of no filter (dB) and each method's "
            "gain over it (dB; the paper reports BD-rate, where lower is better; here higher is better)\n\n"
            + md_table(["sequence", "none (dB)"] + [f"{m} (ΔdB)" for m in methods[1:]], rows)
            + "\n\nPaper ordering (modified+morph ≥ modified ≥ dilation > none): PSNR "
            + ("holds" if r["paper_order_holds_psnr"] else "does not hold") + "; edge-band PSNR "
            + ("holds" if r["paper_order_holds_edge_psnr"] else "does not hold") + "; per sequence: "
            + ", ".join(f"{k} {'holds' if v else 'does not hold'}" for k, v in r["paper_order_holds_per_sequence"].items())
            + "."
        )
    syn, dep = results["synthesis"], results["depth"]
    labels = list(syn)
    parts.append(
        "**All conditions averaged** (depth error on the four GT views, > 1 px is bad)\n\n" + md_table(
            ["variant", "PSNR dB", "edge PSNR dB", "SSIM", "edge SSIM", "MAE px", "bad %", "edge MAE px", "edge bad %"],
            [[m, syn[m]["psnr_db"], syn[m]["edge_psnr_db"], syn[m]["ssim"], syn[m]["edge_ssim"], dep[m]["mae"],
              100 * dep[m]["bad_rate"], dep[m]["edge_mae"], 100 * dep[m]["edge_bad_rate"]] for m in labels],
        )
    )
    parts.append(
        "**PSNR by coding condition** (dB, averaged over sequences, pairs and upsamplers)\n\n" + md_table(
            ["condition"] + methods, [[c] + [v[m] for m in methods] for c, v in results["by_condition"].items()]
        )
    )
    rows = []
    for seq, pairs in results["anchors"].items():
        for pair, a in pairs.items():
            rows.append([seq, pair, a["gt"]["psnr_db"], a["gt"]["edge_psnr_db"], a["gt_filled"]["psnr_db"],
                         a["gt_filled_dilated3"]["psnr_db"], a["gt_filled_dilated3"]["edge_psnr_db"],
                         a["nearest_source_view"]["psnr_db"]])
    gain = float(np.mean([r[5] - r[4] for r in rows]))
    parts.append(
        "**Anchors** (uncoded depth, same renderer): PSNR dB\n\n" + md_table(
            ["sequence", "pair", "GT", "GT edge", "GT filled", "GT filled + 3x3 dilation", "  ...edge",
             "nearest source view"], rows)
        + f"\n\nDilating even the uncoded ground truth gains {gain:.2f} dB on average with this renderer: "
        "these textures' object boundaries extend past the GT depth edges (mixed-colour pixels), so a "
        "foreground grown by one pixel renders better. Plain dilation gets that gain; the modified filters "
        "by design never grow the foreground, which is why dilation can beat them here while having the "
        "largest depth error."
    )
    t = results["throughput"]
    parts.append(
        "**Throughput** 1920x1088 8-bit frames, x2 nearest upsampling + modified dilation + closing (3x3), "
        f"engine FramePipeline: {t['fps_1080p']:.0f} frames/s with two worker threads (one per core); one "
        f"thread {t['fps_1080p_one_thread']:.0f} frames/s ({t['ms_per_frame_one_thread']:.2f} ms wall, "
        f"{t['cpu_ms_per_frame']:.2f} ms CPU, medians of {t['reps']}). Reference, cv2.dilate 3x3 alone in the "
        f"same run: {t['dilate_only_fps']:.0f} frames/s two threads, {t['dilate_only_fps_one_thread']:.0f} one "
        f"thread ({t['dilate_only_cpu_ms']:.2f} ms CPU). Load average during the run: {t['load_average_1min']:.1f} "
        f"on {t['cores']} cores (wall-clock figures are only meaningful on a quiet machine; CPU time is not "
        "inflated by other processes)."
    )
    return "\n\n".join(parts)


if __name__ == "__main__":
    sys.exit(main())
