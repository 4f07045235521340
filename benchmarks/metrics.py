"""PSNR/SSIM: our one module (``workers.common.imagemetrics``) against scikit-image's ``metrics``.

Measures agreement (the SSIM map, the mean SSIM, PSNR) and speed on Middlebury Teddy (a view against
a neighbouring view and against a blurred, noisy copy) at 450x375 and upscaled to 640x480 and
1920x1080, plus what the merge changed: the sweep benchmark's old SSIM used a 13x13 window.

    python -m benchmarks.metrics
"""
from __future__ import annotations

import argparse
import sys

import cv2
import numpy as np

from benchmarks._report import md_table, prog, publish
from benchmarks._timing import load, timed
from workers.common.datasets import dataset
from workers.common.imagemetrics import SSIM_SIGMA, luma, psnr, ssim, ssim_map


def _old_sweep_ssim(a: np.ndarray, b: np.ndarray) -> float:
    """The sweep benchmark's SSIM before the merge: the same formula with OpenCV's default window for
    sigma 1.5 on float64 (13x13)."""
    x, y = luma(a), luma(b)
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2

    def blur(img: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(img, (0, 0), SSIM_SIGMA, borderType=cv2.BORDER_REFLECT)

    mx, my = blur(x), blur(y)
    vx, vy, cxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
    return float((((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))).mean())


def _skimage_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    from skimage.metrics import structural_similarity

    return structural_similarity(luma(a), luma(b), data_range=255, gaussian_weights=True, sigma=SSIM_SIGMA,
                                 use_sample_covariance=False, full=True)[1]


def _skimage_psnr(a: np.ndarray, b: np.ndarray) -> float:
    from skimage.metrics import peak_signal_noise_ratio

    return float(peak_signal_noise_ratio(a, b, data_range=255))


def main() -> int:
    argparse.ArgumentParser(prog=prog(), description=__doc__.split("\n\n")[0]).parse_args()  # --help: no run
    teddy = dataset("multiview", "teddy")
    if teddy is None:
        print("no Middlebury Teddy in $SWEEPCAST_DATA; nothing measured", file=sys.stderr)
        return 1
    view = cv2.imread(str(teddy / "im2.png"))
    pairs = {"neighbour view": cv2.imread(str(teddy / "im3.png")),
             "blur + noise": np.clip(cv2.GaussianBlur(view, (0, 0), 1.0).astype(float)
                                     + np.random.default_rng(0).normal(0, 8, view.shape), 0, 255).astype(np.uint8)}
    rows, agreement = [], {}
    for name, other in pairs.items():
        ours, ref = ssim_map(view, other), _skimage_map(view, other)
        agreement[name] = {"ssim_map_max_abs_diff": float(np.abs(ours - ref).max()), "ssim": ssim(view, other),
                           "ssim_old_sweep_13x13": _old_sweep_ssim(view, other),
                           "psnr_db": psnr(view, other), "psnr_skimage_db": _skimage_psnr(view, other)}
        a = agreement[name]
        rows.append([name, a["ssim"], a["ssim_old_sweep_13x13"], a["ssim"] - a["ssim_old_sweep_13x13"],
                     a["ssim_map_max_abs_diff"], a["psnr_db"], a["psnr_db"] - a["psnr_skimage_db"]])

    speed, speed_rows = {}, []
    for label, size in {"450x375": None, "640x480": (640, 480), "1920x1080": (1920, 1080)}.items():
        a = view if size is None else cv2.resize(view, size)
        b = pairs["blur + noise"] if size is None else cv2.resize(pairs["blur + noise"], size)
        reps = 5 if size == (1920, 1080) else 15
        t_ours, t_sk = timed(lambda: ssim_map(a, b), 1), timed(lambda: _skimage_map(a, b), 1)
        for _ in range(reps):  # interleaved, so that load changes hit both alike
            t_ours.wall += timed(lambda: ssim_map(a, b)).wall
            t_sk.wall += timed(lambda: _skimage_map(a, b)).wall
        t_ours.wall, t_sk.wall = t_ours.wall[1:], t_sk.wall[1:]
        speed[label] = {"ours_ms": 1000 * t_ours.best, "skimage_ms": 1000 * t_sk.best,
                        "skimage_over_ours": t_sk.best / t_ours.best,
                        "median_skimage_over_ours": t_sk.median / t_ours.median}
        speed_rows.append([label, 1000 * t_ours.best, 1000 * t_sk.best, t_sk.best / t_ours.best,
                           t_sk.median / t_ours.median])
    lavg = load()
    print(f"load {lavg}")
    md = (
        "Agreement on Middlebury Teddy view 2 (450x375): our SSIM map against scikit-image 0.26's "
        "`structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, full=True)` on the "
        "same luma, and the sweep benchmark's SSIM before the two copies were merged (13x13 window):\n\n"
        + md_table(["pair", "SSIM", "old sweep SSIM", "change", "max abs map diff to skimage", "PSNR dB",
                    "PSNR - skimage's"], rows)
        + "\n\nSSIM map speed (fastest of the repeats, ms, one thread; the 11x11 Gaussian blur is OpenCV's separable filter, "
          "scikit-image's scipy's `gaussian_filter`):\n\n"
        + md_table(["size", "ours ms", "scikit-image ms", "scikit-image / ours", "same, medians"], speed_rows)
        + f"\n\nLoad average during the run: {lavg} (2 cores; other helpers' work was running).\n"
    )
    publish("metrics", {"agreement": agreement, "speed": speed, "load": lavg}, md)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
