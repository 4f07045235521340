"""Stress run of the compiled depth searches: random rigs, random sizes, misaligned arrays, any thread count.

Each repetition draws a rig (3-8 cameras of different sizes on an arc of 3-150 degrees, some looking away
from the scene), a virtual view (inside the rig or far outside it, a size that is no multiple of the
16 lanes or the 32-column tiles), random images with flat patches (exact zero-variance ties), optional
silhouettes, random per-pixel plane windows, random row bands taken in a random order, and copies of every
array the kernels read or write placed at an address offset from 16, 32 and 64-byte boundaries. Every
search variant (the 16-lane variance search, the per-pixel variance and truncated searches, each with and
without the visual hull) must choose a plane of least cost by the numpy definition
(:mod:`harness.numpy_search`), the two variance searches must agree exactly, the unpruned cost
volume (the input of cost aggregation) must give every plane's cost, and the occlusion fill's cross-view check
on that volume must count the confirming cameras as its numpy definition does. Run it in a subprocess: a memory error then ends that
process with a signal, which the caller reports, instead of killing the test runner.

    python -m harness.kernel_stress --reps 50 --threads 2 --seed 1
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numba
import numpy as np

from workers.camera import Camera
from workers.sweep import kernels
from workers.sweep import lanes as lanes_mod
from workers.sweep.occlusion import confirmed_views
from workers.sweep.renderer import SweepRenderer

from harness.numpy_search import best_plane, confirmations, plane_costs

# per-pixel float64 sums of the reference and the kernels may round a position differently when it lies
# within an ulp of a half step; such a pixel may then pick another plane (seen: < 0.1% of pixels)
MAX_DISAGREEMENT = 0.005
# planes whose costs are equal by definition (the truncated cost when every deviation is capped: trunc2
# for every plane) differ in the last bits with the order of the sums: such a choice is not a disagreement
TIE_RTOL = 1e-12


def disagreement(best: np.ndarray, costs: np.ndarray) -> float:
    """Share of pixels whose chosen plane (h, w) is not a best one of the reference costs (P, h, w):
    a plane costing more than the minimum (beyond rounding), or -1 where a plane qualifies or the reverse."""
    low = costs.min(axis=0)
    chosen = np.take_along_axis(costs, np.maximum(best, 0)[None], axis=0)[0]
    ok = np.where(best >= 0, chosen <= low * (1 + TIE_RTOL), ~np.isfinite(low))
    return float((~ok).mean())


def misaligned(a: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A C-contiguous copy of a whose data starts at a random multiple of its item size past a 64-byte
    boundary, never on one (numpy and numba only promise 16 or 32)."""
    step = a.itemsize
    offsets = [o for o in range(step, 64, step) if o % 16] or [step]
    offset = int(rng.choice(offsets))
    raw = np.empty(a.nbytes + 128, np.uint8)
    start = (-raw.ctypes.data) % 64 + offset
    out = raw[start:start + a.nbytes].view(a.dtype).reshape(a.shape)
    out[...] = a
    assert out.ctypes.data % 64 == offset and out.flags.c_contiguous
    return out


def random_images(rng: np.random.Generator, cams: list[Camera]) -> list[np.ndarray]:
    """Smooth random colour with flat patches (equal samples: exact ties between planes)."""
    out = []
    for c in cams:
        coarse = rng.integers(0, 256, (c.height // 4 + 2, c.width // 4 + 2, 3)).astype(np.float64)
        img = np.kron(coarse, np.ones((4, 4, 1)))[:c.height, :c.width]
        img += rng.normal(0, 12, img.shape)
        for _ in range(rng.integers(0, 3)):
            y, x = rng.integers(0, c.height), rng.integers(0, c.width)
            img[y:y + rng.integers(3, 20), x:x + rng.integers(3, 20)] = rng.integers(0, 256, 3)
        out.append(np.clip(img, 0, 255).astype(np.uint8))
    return out


def random_silhouettes(rng: np.random.Generator, cams: list[Camera]) -> list[np.ndarray]:
    out = []
    for c in cams:
        yy, xx = np.mgrid[:c.height, :c.width]
        m = np.zeros((c.height, c.width), bool)
        for _ in range(rng.integers(1, 4)):
            cx, cy = rng.uniform(0, c.width), rng.uniform(0, c.height)
            rad = rng.uniform(0.2, 0.9) * max(c.width, c.height)
            m |= (xx - cx) ** 2 + (yy - cy) ** 2 < rad**2
        out.append(m)
    return out


def random_case(rng: np.random.Generator) -> dict:
    """One random rig, virtual view, images, planes and windows (see the module's docstring)."""
    n_cam = int(rng.integers(3, 9))
    spread = np.radians(rng.uniform(3, 150))
    radius = rng.uniform(2.0, 4.0)
    cams = []
    for i, a in enumerate(np.linspace(-spread / 2, spread / 2, n_cam) + rng.normal(0, 0.02, n_cam)):
        eye = [radius * np.sin(a), -radius * np.cos(a), rng.uniform(0.2, 1.5)]
        target = rng.normal(0, 0.3, 3) + (rng.normal(0, 1.5, 3) if rng.random() < 0.25 else 0)  # some look away
        cams.append(Camera.look_at(f"c{i}", eye, target, fov_deg=rng.uniform(35, 75),
                                   width=int(rng.integers(23, 91)), height=int(rng.integers(17, 71))))
    where = rng.choice(["inside", "behind", "opposite", "above"])
    a = rng.uniform(-spread / 2, spread / 2)
    r_v = {"inside": radius, "behind": radius * rng.uniform(2.5, 5), "opposite": -radius, "above": radius * 0.3}[where]
    eye = [r_v * np.sin(a), -r_v * np.cos(a), rng.uniform(0.5, 1.2) + (4.0 if where == "above" else 0.0)]
    w, h = int(rng.integers(5, 76)), int(rng.integers(3, 41))
    virtual = Camera.look_at("v", eye, rng.normal(0, 0.2, 3), fov_deg=rng.uniform(30, 90), width=w, height=h)
    P = int(rng.integers(3, 21))
    dist = float(np.linalg.norm(eye))  # planes around the scene's centre, as seen from the view
    near, far = max(0.2, dist - rng.uniform(0.5, 2.0)), dist + rng.uniform(0.5, 3.0)
    s_planes = 1.0 / np.linspace(near, far, P)
    lo = np.zeros((h, w), np.int32)
    hi = np.full((h, w), P - 1, np.int32)
    if rng.random() < 0.5:  # per-pixel windows, some empty (as coarse-to-fine and the hull give)
        lo = rng.integers(0, P, (h, w)).astype(np.int32)
        hi = np.minimum(lo + rng.integers(-1, P, (h, w)), P - 1).astype(np.int32)
    return {"cams": cams, "virtual": virtual, "images": random_images(rng, cams), "s_planes": s_planes,
            "lo": lo, "hi": hi, "bits": int(rng.integers(1, 7)), "min_views": int(rng.integers(1, 4)),
            "sils": random_silhouettes(rng, cams) if rng.random() < 0.5 else None, "where": str(where)}


def run_case(case: dict, rng: np.random.Generator) -> dict:
    """Runs every search variant on one case; returns the worst disagreement with the reference and
    whether the two variance searches agree exactly."""
    cams, virtual, images, sils = case["cams"], case["virtual"], case["images"], case["sils"]
    r = SweepRenderer(cams, images, silhouettes=sils, hull_dilate=0)
    Q, B, _ = r.geometry(virtual)
    camf, cami = r._camera_table(Q, B, virtual.center, case["bits"])
    h, w = case["lo"].shape
    band_h = int(rng.integers(1, 9))
    bands = rng.permutation(-(-h // band_h)).astype(np.int64)
    use_hull = sils is not None
    worst, found, covered = 0.0, {}, []
    for trunc2 in (0.0, float(rng.uniform(50, 5000))):
        costs = plane_costs(r.cameras, images, r.silhouettes() if use_hull else None, virtual, case["s_planes"],
                            case["bits"], trunc2=trunc2, min_views=case["min_views"])
        j = np.arange(len(case["s_planes"]))[:, None, None]
        costs[(j < case["lo"]) | (j > case["hi"])] = np.inf
        for lanes in ((True, False) if trunc2 == 0 else (False,)):
            best = misaligned(np.full((h, w), -7, np.int32), rng)
            cost = misaligned(np.full((h, w), np.nan, np.float32), rng)
            args = [misaligned(a, rng) for a in (camf, cami, r._pix.reshape(-1), r._sils.reshape(-1))]
            kernels.sweep_depth(*args, use_hull, case["min_views"], trunc2, case["bits"],
                                misaligned(case["s_planes"], rng), misaligned(case["lo"], rng),
                                misaligned(case["hi"], rng), misaligned(bands, rng), band_h, best, cost, lanes)
            worst = max(worst, disagreement(best, costs))
            covered.append(float((best_plane(costs) >= 0).mean()))
            found[(trunc2 > 0, lanes)] = (best.copy(), cost.copy())
        if trunc2 == 0:  # the unpruned cost volume (aggregation's input): the same costs, every plane
            P = len(case["s_planes"])
            ssd = misaligned(np.full((h, w, P), np.nan, np.float32), rng)
            votes = misaligned(np.full((h, w, P), np.nan, np.float32), rng)
            lanes_mod.lane_cost_volume(*args, use_hull, case["min_views"], case["bits"],
                                       misaligned(case["s_planes"], rng), misaligned(case["lo"], rng),
                                       misaligned(case["hi"], rng), misaligned(bands, rng), band_h, ssd, votes)
            volume = np.where(votes > 0, ssd / np.maximum(votes, 1), np.inf).transpose(2, 0, 1)
            want = np.where(np.isfinite(costs), costs, np.inf)
            off = ~np.isclose(volume, want, rtol=1e-4, atol=1e-3) & ~(np.isinf(volume) & np.isinf(want))
            worst = max(worst, float(off.mean()))
            # the occlusion fill's cross-view check on that volume (each camera's own winner among the view's
            # hypotheses), misaligned, against its numpy definition
            vol = np.ascontiguousarray(volume.transpose(1, 2, 0), np.float32)
            best_v = best_plane(volume.transpose(0, 1, 2)).astype(np.int32)
            n = confirmed_views(Q, B, misaligned(case["s_planes"], rng), misaligned(vol, rng), misaligned(case["lo"], rng),
                                misaligned(case["hi"], rng), misaligned(best_v, rng), misaligned(r._sizes, rng))
            want_n = confirmations(r.cameras, virtual, case["s_planes"], vol, best_v)
            worst = max(worst, float((n != want_n).mean()))
    (b1, c1), (b2, c2) = found[(False, True)], found[(False, False)]
    same = bool(np.array_equal(b1, b2) and np.array_equal(c1, c2, equal_nan=True))
    return {"disagreement": worst, "variance_searches_equal": same, "with_depth": float(np.mean(covered))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=50)
    ap.add_argument("--threads", type=int, default=2, help="numba threads (NUMBA_NUM_THREADS must allow it)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    numba.set_num_threads(args.threads)
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    worst, unequal, where, with_depth = 0.0, 0, {}, []
    for _ in range(args.reps):
        case = random_case(rng)
        out = run_case(case, rng)
        worst = max(worst, out["disagreement"])
        unequal += not out["variance_searches_equal"]
        with_depth.append(out["with_depth"])
        where[case["where"]] = where.get(case["where"], 0) + 1
    report = {"reps": args.reps, "threads": args.threads, "seed": args.seed, "worst_disagreement": worst,
              "variance_searches_unequal": unequal, "virtual_views": where,
              "pixels_with_depth": float(np.mean(with_depth)), "seconds": time.perf_counter() - t0}
    print(json.dumps(report))
    return 0 if worst <= MAX_DISAGREEMENT and unequal == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
