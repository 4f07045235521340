"""EXIF orientation fixer benchmark (Shima & Shukuya): Tables I-III on real photos, and photos per second.

Accuracy. Every image in ``$SWEEPCAST_DATA/faces/dev`` (all subfolders) is turned by each of the
four rotations and re-encoded as a JPEG (quality 95), and each detector configuration decides
which way is up. A trial is a *success* when the decided rotation undoes the turn, a *reject*
when the detector declines, and *wrong* (the paper's "error") otherwise. ``dogs.jpg`` is a
negative (dog faces, no people): any decision on it is counted separately. As in the paper we
report Table I (acceptance per view, relative to the upright photo), Table II (how many of the
four views were accepted) and Table III (success / reject / error). Configurations:

- ``paper``: Haar whole face + Haar facial parts shipped with OpenCV (the product's default
  without a YuNet model);
- ``paper_mcs``: the paper's exact part cascades (haarcascade_mcs_*, CC BY-NC 4.0, from
  ``../shared/models/haar_mcs``; benchmark only);
- ``yunet``: YuNet alone with the per-face margin rule;
- ``combined``: YuNet faces confirmed by Haar parts or by a decisive YuNet margin (the default
  when a YuNet model is configured).

Speed. ~12-megapixel JPEGs are made by upscaling dev photos. Engine only: ``analyze`` in-process
on one thread and on two threads (OpenCV releases the GIL), with decoding alone timed in the
same run as the baseline. End to end: the service is started as a subprocess
(``python -m app serve``), and a few concurrent clients POST the photos to
``/v1/photos/orientation`` (the clients run on the same machine and take their share of its CPU, which is
counted: the server's, the clients' and everything else's CPU per photo); the server's start-up work (kernel
warm-up from the checkout's kernel cache, ``sweepcast-data/cache/numba``, demo rig, Ray) finishes first; after one warm-up pass (reported
apart), photos per second is the median over repeats, each pass at least two requests per client.

The other orientation benchmarks, each a results section of its own: ``benchmarks.orientation_text`` (what each
photo costs and what is decided, by class), ``benchmarks.orientation_face_sizes`` (the Haar scans on faces of every
size), ``benchmarks.orientation_writers`` (our writers against Exiv2 and ExifTool), ``benchmarks.orientation_throughput``
(issue 21: engines against HTTP at 4 and 50 clients) and ``benchmarks.orientation_library`` (a photo library).

Run: ``python -m benchmarks.orientation [--quick] [--no-http] [--no-speed]`` from the repository root.
"""
from __future__ import annotations

import argparse
import statistics
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks._orientation_photos import (MEGAPIXELS, NEGATIVES, dev_photos, find_photos, make_large_jpegs,
                                            mcs_cascades, rotated_inputs, yunet_model)
from benchmarks._orientation_speed import run_engine_speed, run_http_speed
from benchmarks._report import md_table, prog, publish
from harness.servers import exit_on_sigterm
from workers.common.datasets import data_root
from workers.orientation.detect import DetectorConfig, OrientationDetector, get_detector
from workers.orientation.geometry import ROTATIONS
from workers.orientation.orient import analyze

PAPER = {"success_rate": 0.931, "reject_rate": 0.069, "wrong": 0, "samples": 450}

# Paper's Table I columns, as clockwise views of the upright photo.
TABLE1_COLUMNS = ((0, "0"), (270, "90 CCW"), (180, "180"), (90, "90 CW"))

@dataclass
class Tally:
    """Outcomes of one configuration over all trials."""

    success: int = 0
    reject: int = 0
    wrong: int = 0
    negative_trials: int = 0
    negative_decided: int = 0
    negative_decided_wrong_rotation: int = 0
    view_accepts: dict[int, int] = field(default_factory=lambda: {r: 0 for r in ROTATIONS})
    accept_counts: list[int] = field(default_factory=lambda: [0] * 5)
    wrong_cases: list[str] = field(default_factory=list)
    ms: list[float] = field(default_factory=list)

    @property
    def trials(self) -> int:
        return self.success + self.reject + self.wrong

    def summary(self) -> dict:
        n = max(self.trials, 1)
        return {
            "trials": self.trials, "success": self.success, "reject": self.reject, "wrong": self.wrong,
            "success_rate": self.success / n, "reject_rate": self.reject / n, "wrong_rate": self.wrong / n,
            "negative_trials": self.negative_trials, "negative_decided": self.negative_decided,
            "negative_decided_wrong_rotation": self.negative_decided_wrong_rotation,
            "table1_view_accepts": {label: self.view_accepts[r] for r, label in TABLE1_COLUMNS},
            "table2_accepted_views": {str(k): v for k, v in enumerate(self.accept_counts)},
            "wrong_cases": self.wrong_cases,
            "median_ms_per_photo": statistics.median(self.ms) if self.ms else None,
        }

def configurations(yunet: Path | None, mcs: Path | None) -> dict[str, DetectorConfig]:
    """The face detectors of Tables I-III (faces only: the text cue off)."""
    configs = {"paper": DetectorConfig(method="paper", text=False)}
    if mcs is not None:
        configs["paper_mcs"] = DetectorConfig(method="paper", haar_mcs_dir=mcs, text=False)
    if yunet is not None:
        configs["yunet"] = DetectorConfig(method="yunet", yunet_model=yunet, text=False)
        configs["combined"] = DetectorConfig(method="combined", yunet_model=yunet, text=False)
    return configs

def run_accuracy(photos: list[Path], detectors: dict[str, OrientationDetector],
                 megapixels: float | None = None) -> dict[str, Tally]:
    """Every photo x 4 rotations through every detector (optionally upscaled to ``megapixels``)."""
    tallies = {name: Tally() for name in detectors}
    for i, path in enumerate(photos):
        inputs = rotated_inputs(path, megapixels, 95 if megapixels is None else 90)
        negative = path.name in NEGATIVES
        line = []
        for name, detector in detectors.items():
            t = tallies[name]
            marks = ""
            for r, data in inputs.items():
                report = analyze(data, detector)
                t.ms.append(report.elapsed_ms)
                if negative:  # a decision is not a face result; still, it must not turn the photo wrongly
                    t.negative_trials += 1
                    t.negative_decided += report.rotation_degrees is not None
                    t.negative_decided_wrong_rotation += report.rotation_degrees not in (None, r)
                    marks += "n" if report.rotation_degrees is None else ("d" if report.rotation_degrees == r else "X")
                    continue
                for a in report.accepted_rotations:
                    t.view_accepts[(a - r) % 360] += 1
                t.accept_counts[len(report.accepted_rotations)] += 1
                if report.rotation_degrees == r:
                    t.success += 1
                    marks += "+"
                elif report.rotation_degrees is None:
                    t.reject += 1
                    marks += "."
                else:
                    t.wrong += 1
                    t.wrong_cases.append(f"{path.name} turned {r}: decided {report.rotation_degrees}")
                    marks += "X"
            line.append(f"{name}:{marks}")
        print(f"[{i + 1}/{len(photos)}] {path.name[:40]:40s} " + " ".join(line), flush=True)
    return tallies

def markdown(results: dict) -> str:
    configs = results["configs"]
    def row(name: str, c: dict) -> list:
        return [name, c["trials"], c["success"], c["reject"], c["wrong"], f"{100 * c['success_rate']:.1f}%",
                f"{100 * c['reject_rate']:.1f}%",
                f"{c['negative_decided']}/{c['negative_trials']} ({c['negative_decided_wrong_rotation']} wrong)",
                c["median_ms_per_photo"]]

    rows = [row(name, c) for name, c in configs.items()]
    rows += [row(f"{name} at {MEGAPIXELS:.0f} MP", c) for name, c in results["configs_12mp"].items()]
    rows.append(["paper (Table III, 450 CALTECH faces)", PAPER["samples"], 419, 31, 0, "93.1%", "6.9%", "-", "-"])
    parts = [
        f"{results['dataset']['photos']} photos ({results['dataset']['faces']} with faces, "
        f"{results['dataset']['negatives']} negative) x 4 rotations, re-encoded as JPEG q95.",
        "",
        "Table III (success / reject / wrong). Negatives: decisions made on the dog photo's 4 rotations "
        "(and how many of them turned it wrongly). Rows 'at 12 MP': the photos upscaled to ~12 MP, JPEG q90.",
        "",
        md_table(["config", "trials", "success", "reject", "wrong", "success rate", "reject rate",
                  "negatives decided", "median ms/photo"], rows),
        "",
        "Table I (trials in which the view was accepted; views relative to the upright photo)",
        "",
        md_table(["config"] + [label for _, label in TABLE1_COLUMNS],
                 [[n] + list(c["table1_view_accepts"].values()) for n, c in configs.items()]),
        "",
        "Table II (number of accepted views per trial)",
        "",
        md_table(["config", "0", "1", "2", "3", "4"],
                 [[n] + list(c["table2_accepted_views"].values()) for n, c in configs.items()]),
    ]
    speed = results.get("speed")
    if speed:
        rows = []
        for name, e in speed["engine"].items():
            if isinstance(e, dict):
                rows.append([f"engine {name}", e["photos_per_s_1thread"], e["photos_per_s_2thread"],
                             "OpenCV threads on"])
                rows.append([f"engine {name}", e["photos_per_s_1thread_cv1"], e["photos_per_s_2thread_cv1"],
                             "cv2.setNumThreads(1)"])
                rows.append([f"engine {name}, CPU time", f"{e['cpu_ms_per_photo']:.0f} ms/photo",
                             f"~{2000 / e['cpu_ms_per_photo']:.1f} (estimate)", "2000 / CPU ms: two idle cores"])
        rows.append(["decode only", speed["engine"]["decode_only_photos_per_s_1thread"], "-", "-"])
        for name, h in speed["http"].items():
            if "error" in h:
                rows.append([f"HTTP {name}", "-", "-", f"not measured: {h['error'][:120]}"])
            else:
                rows.append([f"HTTP {name} ({h['clients']} clients)", "-", h["photos_per_s"],
                             f"median latency {h['median_latency_ms']:.0f} ms; passes "
                             + ", ".join(f"{r:.1f}" for r in h["rates"])
                             + f" (after a warm-up pass at {h['first_pass_photos_per_s']:.1f})"])
        parts += ["", f"Speed on {speed['photos']} JPEGs of ~{MEGAPIXELS:.0f} MP "
                      f"({speed['mean_megabytes']:.1f} MB each), photos per second (median of {speed['repeats']})",
                  "", md_table(["path", "1 thread", "2 threads / concurrent", "note"], rows)]
    return "\n".join(parts)


def main() -> int:
    parser = argparse.ArgumentParser(prog=prog(), description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a third of the photos, fewer speed repeats")
    parser.add_argument("--no-http", action="store_true", help="skip the end-to-end HTTP measurement")
    parser.add_argument("--no-speed", action="store_true", help="accuracy only")
    parser.add_argument("--clients", type=int, default=4, help="concurrent HTTP clients (default 4)")
    args = parser.parse_args()
    faces_dir = dev_photos()
    if faces_dir is None:
        print(f"skipped: no face photos at {data_root() / 'faces' / 'dev'} (set SWEEPCAST_DATA)")
        return 0
    yunet, mcs = yunet_model(), mcs_cascades()
    if yunet is None:
        print("note: no YuNet model beside the data; yunet and combined are not measured")

    photos = find_photos(faces_dir)
    if args.quick:
        photos = [p for i, p in enumerate(photos) if i % 3 == 0 or p.name in NEGATIVES]
    detectors = {name: get_detector(cfg) for name, cfg in configurations(yunet, mcs).items()}
    tallies = run_accuracy(photos, detectors)
    print(f"--- the same photos upscaled to ~{MEGAPIXELS:.0f} MP (the speed test's size)", flush=True)
    big_detectors = {n: d for n, d in detectors.items() if n in ("paper", "combined")}
    big_tallies = run_accuracy(photos, big_detectors, MEGAPIXELS)
    negatives = sum(p.name in NEGATIVES for p in photos)
    results: dict = {
        "dataset": {"photos": len(photos), "faces": len(photos) - negatives, "negatives": negatives,
                    "rotations": list(ROTATIONS), "jpeg_quality": 95},
        "configs": {name: t.summary() for name, t in tallies.items()},
        "configs_12mp": {name: t.summary() for name, t in big_tallies.items()},
        "paper_table3": PAPER,
        "default_config": "combined" if yunet is not None else "paper",
        "photos_per_s": None,
    }
    if not args.no_speed:
        repeats = 2 if args.quick else 5
        large = make_large_jpegs(photos, 6 if args.quick else 12)
        speed_detectors = {n: d for n, d in detectors.items() if n in ("paper", "combined")}
        speed: dict = {"photos": len(large), "repeats": repeats, "megapixels": MEGAPIXELS,
                       "mean_megabytes": float(np.mean([len(b) for b in large]) / 1e6),
                       "engine": run_engine_speed(large, speed_detectors, repeats), "http": {}}
        if not args.no_http:
            servers = {"paper": None} | ({"combined": yunet} if yunet is not None else {})
            for name, model in servers.items():
                speed["http"][name] = run_http_speed(large, model, args.clients, repeats)
                print(f"http {name}: {speed['http'][name]}", flush=True)
        results["speed"] = speed
        default_http = speed["http"].get(results["default_config"], {})
        results["photos_per_s"] = default_http.get("photos_per_s")
    for name, c in [*results["configs"].items(), *((f"{n}@12MP", c) for n, c in results["configs_12mp"].items())]:
        print(f"{name:10s} success {c['success_rate']:.3f} reject {c['reject_rate']:.3f} wrong {c['wrong']} "
              f"negatives decided {c['negative_decided']}/{c['negative_trials']}")
    publish("orientation", results, markdown(results))
    return 0


if __name__ == "__main__":
    with exit_on_sigterm():  # SIGTERM unwinds the serve_app block, which stops the server and its Ray
        sys.exit(main())
