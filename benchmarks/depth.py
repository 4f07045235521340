"""Depth post-filter benchmark, judged the paper's way: BD-rate of synthesised views with a real codec.

Lee, Yang & Oh (Table I) code multi-view video plus half-resolution depth with 3D-ATM, upsample the
decoded depth, post-filter it, synthesise intermediate views (VSRS) and report the Bjøntegaard
delta rate (BD-rate) of each filter against the anchor. The analogue here, on Middlebury Teddy
(im4 from im2+im6 and from im3+im5) and Art (view3 from view1+view5 and from view2+view4):

1. Depth: ground-truth disparity as 8-bit levels linear in disparity (MPEG inverse depth), area-
   downsampled by 2 (``--factor``), coded with libx264 (H.264) and, when PyAV has it, libx265 (HEVC)
   at constant QP 22/27/32/37, all-intra, as the luma of a 4:2:0 video with chroma 128 (PyAV).
2. Texture: the source views coded with the same codec and QP (4:2:0); the decoder-side guide of
   the edge-aware methods is this decoded texture, never the original.
3. Decoder side: upsample the decoded depth (nearest or bilinear), post-filter with each method,
   synthesise the targets with the project's DIBR (``workers.depth.dibr``).
4. Rate: texture + depth bits of the coded source views (SEI messages excluded). Quality: luma
   (Y) PSNR of the synthesised views against the real target views, averaged over the two pairs.
5. BD-rate / BD-PSNR (``bjontegaard`` package: piecewise-cubic PCHIP as in the CTC spreadsheet,
   and VCEG-M33 cubic) of every method against no filter and against dilation, per sequence and
   on average: the layout of Table I.

Depth of views without GT (Teddy im3/im5/im4, Art view2/view4/view3) is derived by warping both GT
maps to the view and keeping the nearer surface (exact wherever one GT view sees it); unknown GT
pixels are filled from the background side before coding. Depth errors (MAE, > 1 px bad rate) are
measured on the GT views only, where GT is known.

Run: ``nice -n 10 python -m benchmarks.depth [--quick]`` from the repository root (``--quick``:
H.264 only, nearest upsampling, no throughput run; it does not publish).
"""
from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from benchmarks._report import RESULTS_DIR, md_table, prog, publish
from benchmarks._timing import timed
from benchmarks.bd import bd_pair
from workers.common.datasets import dataset
from workers.common.imagemetrics import psnr
from workers.depth import dibr, metrics
from workers.depth.levels import disparity_to_levels, levels_to_disparity
from workers.depth.methods import FilterOptions, apply_method, postprocess
from workers.depth.pipeline import FramePipeline
from workers.depth.upsample import upsample
from workers.depth.video import available_codecs, code_depth, code_texture

QPS = (22, 27, 32, 37)
PAPER_METHODS = ["dilation", "modified", "modified_morph"]
EDGE_AWARE = ["wmf", "jbu"]  # the two edge-aware references the paper cites ([9], [7])
# label -> steps: the first (method, option overrides) runs on the decoded low-resolution map with
# the upsampler (methods.postprocess), the others on its output (methods.apply_method)
VARIANTS: dict[str, list[tuple[str, dict]]] = {
    "none": [("none", {})],
    **{m: [(m, {})] for m in PAPER_METHODS + EDGE_AWARE},
    "jbu+dilation": [("jbu", {}), ("dilation", {})],
    "wmf_dilation": [("wmf_dilation", {})],
}
EDGE_JUMP_PX = 2.0  # a 3x3 disparity span above this (reference-baseline pixels) is a depth edge
EDGE_RADIUS = 3
BAD_PX = 1.0
FIGURE = "depth_edge_band.png"


@dataclass(frozen=True)
class Sequence:
    name: str
    folder: str
    image: str  # file name pattern of view k
    gt: dict[int, tuple[str, float]]  # view -> (file, divisor giving disparity in pixels)
    spacing: int  # view spacings between the two GT views (their disparity's reference baseline)
    pairs: tuple[tuple[int, int, int], ...]  # (left, right, target)

    @property
    def sources(self) -> list[int]:
        return sorted({v for left, right, _ in self.pairs for v in (left, right)})


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

    @property
    def planes(self) -> tuple[float, float]:
        """(z_near, z_far) of levels linear in disparity (MPEG inverse depth with f * B = 1)."""
        lo, hi = self.d_range
        return 1.0 / hi, 1.0 / lo

    def levels(self) -> dict[int, np.ndarray]:
        """8-bit levels (H, W) uint8 of every source view's (hole-filled) disparity."""
        zn, zf = self.planes
        return {k: disparity_to_levels(dibr.fill_depth_holes(self.depth[k]), zn, zf, 1.0) for k in self.seq.sources}


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


@dataclass
class CodedViews:
    """One rate point: the source views as a decoder has them after coding at one QP."""

    textures: dict[int, np.ndarray]  # decoded (H, W, 3) uint8 BGR
    depth_low: dict[int, np.ndarray]  # decoded (h, w) uint8 levels at the coded (low) resolution
    texture_bits: int
    depth_bits: int


def code_views(scene: SceneData, levels: dict[int, np.ndarray], factor: int, codec: str, qp: int) -> CodedViews:
    """Area-downsample the depth by ``factor``, code depth and textures of the source views (one
    all-intra stream each), decode both."""
    views = scene.seq.sources
    h, w = levels[views[0]].shape
    low = [cv2.resize(levels[k], (round(w / factor), round(h / factor)), interpolation=cv2.INTER_AREA) for k in views]
    depth, depth_bits = code_depth(low, codec, qp)
    textures, texture_bits = code_texture([scene.images[k] for k in views], codec, qp)
    return CodedViews(dict(zip(views, textures)), dict(zip(views, depth)), texture_bits, depth_bits)


def options_for(factor: int, base: FilterOptions) -> FilterOptions:
    """Windows that cover the blur of an upsampling by ``factor`` (3 and 9 pixels for x2)."""
    return replace(base, window=factor + 1, guide_window=2 * factor + 5)


def run_variant(
    coded: CodedViews, steps: list[tuple[str, dict]], upsampler: str, opts: FilterOptions,
) -> dict[int, np.ndarray]:
    """Decoder-side depth of every source view: (H, W) uint8 levels at the texture size."""
    out = {}
    for k, low in coded.depth_low.items():
        guide = coded.textures[k]
        (first, over), rest = steps[0], steps[1:]
        d = postprocess(low, first, upsampler=upsampler, guide=guide, options=replace(opts, **over))
        for method, over in rest:
            d = apply_method(d, method, guide, replace(opts, **over))
        out[k] = d
    return out


def luma(image: np.ndarray) -> np.ndarray:
    """Y (BT.601) of a BGR image (H, W, 3) uint8 -> (H, W) uint8."""
    return cv2.cvtColor(image, cv2.COLOR_BGR2YUV)[..., 0]


def edge_band_of(disp: np.ndarray) -> np.ndarray:
    return metrics.edge_band(np.nan_to_num(disp, nan=0.0), EDGE_JUMP_PX, EDGE_RADIUS, np.isfinite(disp))


def synthesise(scene: SceneData, coded: CodedViews, disp: dict[int, np.ndarray], pair: tuple[int, int, int]) -> np.ndarray:
    """The target of ``pair`` from the decoded textures and the given disparities: (H, W, 3) uint8."""
    left, right, target = pair
    s = scene.seq.spacing
    return dibr.synthesize_rectified(
        [coded.textures[left], coded.textures[right]], [disp[left], disp[right]],
        [(target - left) / s, (target - right) / s],
    ).image


def rd_point(scene: SceneData, coded: CodedViews, levels: dict[int, np.ndarray]) -> dict:
    """Scores of one method at one rate: Y-PSNR of the synthesised views (mean of the pairs and per
    pair), edge-band Y-PSNR, and the depth error on the GT views."""
    zn, zf = scene.planes
    disp = {k: levels_to_disparity(v, zn, zf, 1.0) for k, v in levels.items()}
    pairs = {}
    for pair in scene.seq.pairs:
        real = luma(scene.images[pair[2]])
        syn = luma(synthesise(scene, coded, disp, pair))
        band = edge_band_of(scene.depth[pair[2]])
        pairs["{}+{}->{}".format(*pair)] = {"y_psnr_db": psnr(syn, real),
                                            "edge_y_psnr_db": psnr(syn, real, band)}
    errors = [metrics.depth_errors(disp[k], np.nan_to_num(t), np.isfinite(t), BAD_PX)
              for k, t in scene.gt.items() if k in disp]
    return {
        "rate_bits": coded.texture_bits + coded.depth_bits, "texture_bits": coded.texture_bits,
        "depth_bits": coded.depth_bits,
        "y_psnr_db": float(np.mean([p["y_psnr_db"] for p in pairs.values()])),
        "edge_y_psnr_db": float(np.mean([p["edge_y_psnr_db"] for p in pairs.values()])),
        "pairs": pairs,
        "depth_mae_px": float(np.mean([e["mae"] for e in errors])),
        "depth_bad_rate": float(np.mean([e["bad_rate"] for e in errors])),
    }


def run_sequence(
    scene: SceneData, codecs: list[str], upsamplers: list[str], factor: int, qps: tuple[int, ...],
    variants: dict[str, list[tuple[str, dict]]], base: FilterOptions,
) -> dict[str, dict[str, dict[str, list[dict]]]]:
    """RD points: codec -> upsampler -> variant -> one point per QP (ascending QP)."""
    levels = scene.levels()
    opts = options_for(factor, base)
    out: dict = {c: {u: {v: [] for v in variants} for u in upsamplers} for c in codecs}
    for codec in codecs:
        for qp in qps:
            t0 = time.perf_counter()
            coded = code_views(scene, levels, factor, codec, qp)
            for up in upsamplers:
                for label, steps in variants.items():
                    point = rd_point(scene, coded, run_variant(coded, steps, up, opts))
                    out[codec][up][label].append({"qp": qp, **point})
            print(f"{scene.seq.name} {codec} qp={qp}: {time.perf_counter() - t0:.1f}s", file=sys.stderr)
    return out


def bd_tables(points: dict, labels: list[str], key: str = "y_psnr_db") -> dict:
    """BD figures: codec -> upsampler -> anchor ("none"/"dilation") -> variant -> sequence (and
    "AVG.", the mean over sequences, as in Table I) -> :func:`benchmarks.bd.bd_pair` figures."""
    out: dict = {}
    for seq, by_codec in points.items():
        for codec, by_up in by_codec.items():
            for up, curves in by_up.items():
                for anchor in ("none", "dilation"):
                    a = curves[anchor]
                    for label in labels:
                        t = curves[label]
                        fig = bd_pair([p["rate_bits"] for p in a], [p[key] for p in a],
                                      [p["rate_bits"] for p in t], [p[key] for p in t])
                        out.setdefault(codec, {}).setdefault(up, {}).setdefault(anchor, {}).setdefault(label, {})[seq] = fig
    for by_up in out.values():
        for by_anchor in by_up.values():
            for by_label in by_anchor.values():
                for label, by_seq in by_label.items():
                    by_seq["AVG."] = {k: float(np.mean([f[k] for f in by_seq.values()])) for k in next(iter(by_seq.values()))}
    return out


def paper_order(by_anchor: dict, where: str) -> dict[str, bool | None]:
    """The paper's claim (modified + morphology >= modified >= dilation > no filter) at ``where``
    (a sequence or "AVG."), judged two ways: by BD-PSNR against no filter (always defined: the rates
    are the anchor's) and by BD-rate against dilation (None where a curve pair does not overlap)."""
    p = {m: by_anchor["none"][m][where]["psnr_pchip"] for m in PAPER_METHODS}
    r = {m: by_anchor["dilation"][m][where]["rate_pchip"] for m in ("modified", "modified_morph")}
    by_rate = None if not all(np.isfinite(list(r.values()))) else r["modified_morph"] <= r["modified"] <= 0
    return {"bd_psnr": p["modified_morph"] >= p["modified"] >= p["dilation"] > 0, "bd_rate_vs_dilation": by_rate,
            "morphology_helps": p["modified_morph"] >= p["modified"]}


# --- the picture of the edge band ------------------------------------------------------------------
FIGURE_METHODS = ["none", "dilation", "modified_morph", "wmf_dilation"]


def edge_band_figure(scene: SceneData, codec: str, qp: int, factor: int, upsampler: str, base: FilterOptions,
                     path: Path, size: tuple[int, int] = (96, 64), zoom: int = 4) -> dict:
    """PNG of the synthesised target around the depth edge where dilation and the paper's filter
    differ most, at one rate: top row the real view and the synthesised ones (FIGURE_METHODS), bottom
    row the GT disparity and each view's absolute luma error x4, with the GT edge band outlined in
    red. Returns what it shows."""
    pair = scene.seq.pairs[0]
    coded = code_views(scene, scene.levels(), factor, codec, qp)
    opts = options_for(factor, base)
    zn, zf = scene.planes
    real = scene.images[pair[2]]
    views = {}
    for m in FIGURE_METHODS:
        levels = run_variant(coded, VARIANTS[m], upsampler, opts)
        views[m] = synthesise(scene, coded, {k: levels_to_disparity(v, zn, zf, 1.0) for k, v in levels.items()}, pair)
    err = {m: np.abs(luma(v).astype(np.int16) - luma(real)).astype(np.float32) for m, v in views.items()}
    band = edge_band_of(scene.depth[pair[2]])
    w, h = size
    score = cv2.boxFilter(np.abs(err["modified_morph"] - err["dilation"]) * band, -1, (w, h), normalize=False)
    cy, cx = np.unravel_index(np.argmax(score[h // 2:-h // 2, w // 2:-w // 2]), score[h // 2:-h // 2, w // 2:-w // 2].shape)
    y0, x0 = int(cy), int(cx)  # top-left of the best window (the search excluded half-windows at the borders)
    crop = (slice(y0, y0 + h), slice(x0, x0 + w))
    outline = _outline(band[crop], zoom)
    gt = np.nan_to_num(scene.depth[pair[2]][crop], nan=0.0)
    gt_img = cv2.applyColorMap(cv2.normalize(gt, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8), cv2.COLORMAP_VIRIDIS)
    top = [_panel(real[crop], "real view", zoom)]
    bottom = [_panel(gt_img, "GT disparity, band outlined", zoom, outline)]
    for m in FIGURE_METHODS:
        top.append(_panel(views[m][crop], m, zoom))
        e = cv2.cvtColor(np.clip(err[m][crop] * 4, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
        band_db = psnr(luma(views[m]), luma(real), band)
        bottom.append(_panel(e, f"|Y err| x4, band {band_db:.2f} dB", zoom, outline))
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.vstack([np.hstack(top), np.hstack(bottom)]))
    return {"file": str(path.relative_to(Path(__file__).resolve().parents[1])), "sequence": scene.seq.name,
            "pair": "{}+{}->{}".format(*pair), "codec": codec, "qp": qp, "upsampler": upsampler,
            "crop_xywh": [x0, y0, w, h],
            "edge_y_psnr_db": {m: psnr(luma(v), luma(real), band) for m, v in views.items()}}


def _outline(mask: np.ndarray, zoom: int) -> np.ndarray:
    """One-pixel outline (bool, zoomed size) of a (h, w) bool mask zoomed ``zoom`` times."""
    big = cv2.resize(mask.astype(np.uint8), None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST)
    return cv2.morphologyEx(big, cv2.MORPH_GRADIENT, np.ones((2, 2), np.uint8)) > 0


def _panel(image: np.ndarray, label: str, zoom: int, outline: np.ndarray | None = None) -> np.ndarray:
    """A zoomed crop with a label above it, and a red outline drawn over it when given."""
    big = cv2.resize(image, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST)
    if outline is not None:
        big[outline] = (0, 0, 255)
    big = cv2.copyMakeBorder(big, 22, 2, 2, 2, cv2.BORDER_CONSTANT, value=(255, 255, 255))
    cv2.putText(big, label, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return big


# --- throughput (the engine's frame-rate path) ----------------------------------------------------
def jpeg(levels: np.ndarray, quality: int) -> np.ndarray:
    """(H, W) uint8 through JPEG at ``quality`` (coding noise for the throughput frame)."""
    ok, buf = cv2.imencode(".jpg", levels, [cv2.IMWRITE_JPEG_QUALITY, quality])
    return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)


def synthetic_low_res_frame() -> np.ndarray:
    """A 960x544 decoded depth frame: nearer discs over a background, JPEG-coded."""
    rng = np.random.default_rng(0)
    low = np.full((544, 960), 60, np.uint8)
    for _ in range(40):
        c = (int(rng.integers(0, 960)), int(rng.integers(0, 544)))
        cv2.circle(low, c, int(rng.integers(10, 120)), int(rng.integers(80, 250)), -1)
    return jpeg(low, 60)


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

    pipe, dil = timed(make_pipeline(), reps), timed(make_dilate(), reps)
    pipe_wall, pipe_cpu, dil_wall, dil_cpu = pipe.median, pipe.median_cpu, dil.median, dil.median_cpu
    fps2 = _two_workers(make_pipeline, reps)
    dil_fps2 = _two_workers(make_dilate, reps)
    return {
        "fps_1080p": fps2, "fps_1080p_one_thread": 1.0 / pipe_wall, "cpu_ms_per_frame": 1000 * pipe_cpu,
        "ms_per_frame_one_thread": 1000 * pipe_wall, "dilate_only_fps": dil_fps2,
        "dilate_only_fps_one_thread": 1.0 / dil_wall, "dilate_only_cpu_ms": 1000 * dil_cpu, "reps": reps,
        "cores": os.cpu_count(), "load_average_1min": os.getloadavg()[0],
    }


# --- the report ------------------------------------------------------------------------------------
def summarise(points: dict, labels: list[str], grid: dict, base: FilterOptions) -> dict:
    """Everything RESULTS.md and the JSON need: BD tables, orderings, mean scores."""
    compared = [m for m in labels if m != "none"]
    bd = bd_tables(points, compared)
    order: dict = {}
    for codec, by_up in bd.items():
        for up, by_anchor in by_up.items():
            vs_none = by_anchor["none"]
            where = list(next(iter(vs_none.values())))
            order.setdefault(codec, {})[up] = {w: paper_order(by_anchor, w) for w in where}
    means = {}
    for label in labels:
        pts = [p for by_codec in points.values() for by_up in by_codec.values()
               for curves in by_up.values() for p in curves[label]]
        means[label] = {k: float(np.mean([p[k] for p in pts]))
                        for k in ("y_psnr_db", "edge_y_psnr_db", "depth_mae_px", "depth_bad_rate")}
    return {
        "config": {**grid, "rate": "texture + depth bits of the coded source views, SEI excluded",
                   "quality": "Y-PSNR of the synthesised views against the real views, mean of the two pairs",
                   "levels": "8-bit, linear in disparity (MPEG inverse depth)", "downsampling": "area",
                   "window": "factor + 1", "guide_window": "2 * factor + 5", "filter_options": base.__dict__,
                   "variants": {k: [[m, o] for m, o in v] for k, v in VARIANTS.items() if k in labels},
                   "edge_jump_px": EDGE_JUMP_PX, "edge_radius_px": EDGE_RADIUS, "bad_pixel_threshold_px": BAD_PX},
        "bd": bd, "paper_order_holds": order, "means": means, "points": points,
    }


def _cell(fig: dict, key: str = "rate_pchip") -> str:
    v = fig[key]
    if not np.isfinite(v):
        return "n/a"
    mark = "" if fig["overlap"] >= 0.5 or not key.startswith("rate") else "*"
    return f"{v:.2f}{mark}"


def _bd_table(by_anchor: dict, labels: list[str], anchor: str, key: str) -> str:
    cols = [m for m in labels if m not in ("none", anchor)]
    seqs = list(next(iter(by_anchor[anchor].values())))
    rows = [[s] + [_cell(by_anchor[anchor][m][s], key) for m in cols] for s in seqs]
    return md_table(["sequence"] + cols, rows)


def _holds(value: bool | None) -> str:
    return "undetermined (no overlap)" if value is None else ("holds" if value else "does not hold")


def markdown(results: dict, grid: dict, labels: list[str]) -> str:
    qps = "/".join(map(str, grid["qps"]))
    parts = [
        f"Middlebury Teddy (im4 from im2+im6 and im3+im5) and Art (view3 from view1+view5 and view2+view4). "
        f"Depth: GT disparity as 8-bit levels, area-downsampled x{grid['factor']}, coded all-intra as the luma "
        f"of a 4:2:0 video (chroma 128) with {', '.join(grid['codecs'])} through PyAV at QP {qps} (ipratio 1); "
        "textures of the source views coded with the same codec and QP; the decoder upsamples the decoded depth "
        f"({' / '.join(grid['upsamplers'])}), post-filters it (window {grid['factor'] + 1}, closing 3x3; wmf window "
        f"{2 * grid['factor'] + 5}; jbu radius 2 low-res px, sigma_color 12) with the decoded texture as the "
        "guide, and synthesises the targets with workers.depth.dibr. Rate: texture + depth bits (SEI excluded); "
        "quality: Y-PSNR of the synthesised views against the real views. BD figures from the `bjontegaard` "
        "package: PCHIP (the CTC spreadsheet's interpolation); VCEG-M33 cubic in the JSON. `*`: the PSNR ranges "
        "of the two curves overlap on less than half of their union (a post-filter moves the whole curve up by "
        "about as much as the QP range spans, so BD-rate is integrated over a short interval there); `n/a`: no "
        "overlap. BD-PSNR needs no such care: the filter leaves the bitstream, and so the rates, unchanged.",
    ]
    for codec, by_up in results["bd"].items():
        for up, by_anchor in by_up.items():
            order = results["paper_order_holds"][codec][up]
            parts.append(
                f"**Table I analogue, {codec}, {up} upsampling: BD-rate (%) against no filter** (lower is better)\n\n"
                + _bd_table(by_anchor, labels, "none", "rate_pchip")
                + f"\n\n**{codec}, {up}: BD-rate (%) against dilation**\n\n"
                + _bd_table(by_anchor, labels, "dilation", "rate_pchip")
                + f"\n\n**{codec}, {up}: BD-PSNR (dB) against no filter** (higher is better)\n\n"
                + _bd_table(by_anchor, labels, "none", "psnr_pchip")
                + "\n\nPaper ordering (modified + morphology ≥ modified ≥ dilation > none) by BD-PSNR: "
                + ", ".join(f"{w} {_holds(v['bd_psnr'])}" for w, v in order.items())
                + "; by BD-rate against dilation: "
                + ", ".join(f"{w} {_holds(v['bd_rate_vs_dilation'])}" for w, v in order.items())
                + "; morphology improves on modified dilation: "
                + ", ".join(f"{w} {_holds(v['morphology_helps'])}" for w, v in order.items()) + "."
            )
    m = results["means"]
    parts.append("**Means over every rate point** (depth error on the GT views; > 1 px is bad)\n\n" + md_table(
        ["method", "Y-PSNR dB", "edge-band Y-PSNR dB", "depth MAE px", "bad %"],
        [[k, v["y_psnr_db"], v["edge_y_psnr_db"], v["depth_mae_px"], 100 * v["depth_bad_rate"]] for k, v in m.items()]))
    fig = results.get("figure")
    if fig:
        parts.append(
            f"**Edge band** ({fig['file']}): {fig['sequence']} {fig['pair']}, {fig['codec']} QP {fig['qp']}, "
            f"{fig['upsampler']} upsampling, crop x,y,w,h = {fig['crop_xywh']}; top: real view and the synthesised "
            "views, bottom: GT disparity and each view's |Y error| x4, the GT edge band outlined in red. Edge-band Y-PSNR (whole image): "
            + ", ".join(f"{k} {v:.2f} dB" for k, v in fig["edge_y_psnr_db"].items()) + ". The object boundaries "
            "of these textures are a pixel or two wider than the GT depth edges (mixed foreground/background "
            "colours). The modified filters by design never move the depth edge outwards, so those pixels are "
            "warped with the background and leave a ghost outline beside the foreground; plain dilation grows "
            "the foreground by a pixel and carries them with it, which is why it beats the paper's filters here "
            "although its depth error is the largest. Where upsampling leaves the edge blocky (nearest) the "
            "ghost is widest; wmf_dilation first moves the edge onto the texture edge, then grows it by a pixel."
        )
    t = results.get("throughput")
    if t:
        parts.append(
            "**Throughput** 1920x1088 8-bit frames, x2 nearest upsampling + modified dilation + closing (3x3), "
            f"engine FramePipeline: {t['fps_1080p']:.0f} frames/s with two worker threads (one per core); one "
            f"thread {t['fps_1080p_one_thread']:.0f} frames/s ({t['ms_per_frame_one_thread']:.2f} ms wall, "
            f"{t['cpu_ms_per_frame']:.2f} ms CPU, medians of {t['reps']}). Reference, cv2.dilate 3x3 alone in the "
            f"same run: {t['dilate_only_fps']:.0f} frames/s two threads, {t['dilate_only_fps_one_thread']:.0f} one "
            f"thread ({t['dilate_only_cpu_ms']:.2f} ms CPU). Load average during the run: "
            f"{t['load_average_1min']:.1f} on {t['cores']} cores (wall-clock figures are only meaningful on a quiet "
            "machine; CPU time is not inflated by other processes)."
        )
    return "\n\n".join(parts)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog=prog(), description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="H.264 only, nearest upsampling, no throughput; not published")
    ap.add_argument("--factor", type=int, default=2, help="depth downsampling factor (default 2)")
    ap.add_argument("--qps", type=int, nargs=4, default=list(QPS), help="four QPs (default 22 27 32 37)")
    args = ap.parse_args(argv)
    roots = {s.name: dataset("multiview", s.folder) for s in SEQUENCES}
    missing = [n for n, r in roots.items() if r is None]
    if missing:
        print(f"skipping the depth benchmark: multiview data for {', '.join(missing)} not found "
              "(set $SWEEPCAST_DATA to the data folder)")
        return 0
    codecs = ["h264"] if args.quick else available_codecs()
    grid = {"codecs": codecs, "upsamplers": ["nearest"] if args.quick else ["nearest", "bilinear"],
            "factor": args.factor, "qps": list(args.qps)}
    base = FilterOptions()
    scenes = [load_scene(s, roots[s.name]) for s in SEQUENCES]
    points = {s.seq.name: run_sequence(s, codecs, grid["upsamplers"], args.factor, tuple(args.qps), VARIANTS, base)
              for s in scenes}
    labels = list(VARIANTS)
    results = summarise(points, labels, grid, base)
    results["figure"] = edge_band_figure(scenes[0], "h264", args.qps[2], args.factor, "nearest", base,
                                         RESULTS_DIR / FIGURE)
    if not args.quick:
        results["throughput"] = throughput(300)
    text = markdown(results, grid, labels)
    if not args.quick:
        publish("depth", results, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
