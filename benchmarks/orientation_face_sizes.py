"""Faces of every size (section orientation_face_sizes; issue 33): the paper's detector with the Haar scans of the last
releases and the short-side rule on the dev faces scaled to 5-45 % of a 2048 x 1365 photo (:mod:`benchmarks._face_sizes`).

Run: ``python -m benchmarks.orientation_face_sizes [--quick]`` from the repository root (the dev photos and the YuNet
model beside the data: YuNet finds the face each photo is scaled around).
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import cv2

from benchmarks._orientation_photos import NEGATIVES, dev_photos, find_photos, rotated_inputs, yunet_model
from benchmarks._report import md_table, prog, publish
from benchmarks._timing import load_note
from workers.orientation.detect import PaperDetector
from workers.orientation.faces import LongSideScan, ShortSideScan
from workers.orientation.geometry import rotate_view
from workers.orientation.orient import analyze
from workers.orientation.parts import PartSpec

FACE_SIZE_TURNS = (0, 270)
"""Turns of each face-size variant tried (upright and a quarter turn: a landscape scanned as a portrait too; the
Haar search sees all four views in every trial)."""

def face_size_configs() -> dict[str, tuple]:
    """The Haar searches compared on faces of every size: the releases' fixed long sides, the rule (short side) alone,
    and the engine's (the rule, then the previous release's search on a photo the rule found no face in); each as
    (scan, pyramid step, neighbours, second search)."""
    from workers.orientation.detect import (HAAR_FACE_PX, HAAR_MIN_NEIGHBORS, HAAR_SCALE_FACTOR, HAAR_SECOND_SEARCH,
                                            HAAR_SMALLEST_FACE, PREVIOUS_HAAR)

    rule = f"rule: 1/{round(1 / HAAR_SMALLEST_FACE)} of the short side at {HAAR_FACE_PX} px"
    scan = ShortSideScan(HAAR_SMALLEST_FACE, HAAR_FACE_PX)
    return {
        "400 px long side (two releases ago)": (LongSideScan(400, 20), 1.2, 3, None),
        "320 px long side (the regression)": (LongSideScan(320, 20), 1.2, 3, None),
        "360 px long side (previous release)": (*PREVIOUS_HAAR, None),
        f"{rule}, step 1.35": (scan, 1.35, HAAR_MIN_NEIGHBORS, None),
        f"{rule} ({round(HAAR_FACE_PX / HAAR_SMALLEST_FACE)} px short side), step {HAAR_SCALE_FACTOR}, alone": (
            scan, HAAR_SCALE_FACTOR, HAAR_MIN_NEIGHBORS, None),
        f"{rule}, step {HAAR_SCALE_FACTOR}, then the 360 px search where it finds no face (engine)": (
            scan, HAAR_SCALE_FACTOR, HAAR_MIN_NEIGHBORS, HAAR_SECOND_SEARCH),
    }

def run_face_sizes(photos: list[Path], yunet: Path) -> dict:
    """Section orientation_face_sizes: every Haar scan on the face-size set (:mod:`benchmarks._face_sizes`), the
    paper's detector alone (Haar face + parts; text off): decided / wrong per face share, CPU ms per photo."""
    from benchmarks._face_sizes import CANVAS, FACE_SHARES, face_size_set

    load_before = os.getloadavg()[0]
    cv2.setNumThreads(1)
    configs = {name: PaperDetector(PartSpec.opencv(), name=name, scan=scan, scale_factor=step, min_neighbors=n,
                                   second=second)
               for name, (scan, step, n, second) in face_size_configs().items()}
    cells: dict = {name: {str(sh): {"trials": 0, "decided": 0, "wrong": 0} for sh in FACE_SHARES} for name in configs}
    cpu: dict = {name: [] for name in configs}
    photos_used: set = set()
    for name_photo, share, image in face_size_set([p for p in photos if p.name not in NEGATIVES], yunet):
        photos_used.add(name_photo)
        for turn in FACE_SIZE_TURNS:
            ok, buf = cv2.imencode(".jpg", rotate_view(image, (360 - turn) % 360), [cv2.IMWRITE_JPEG_QUALITY, 90])
            data = buf.tobytes()
            marks = ""
            for name, detector in configs.items():
                start = time.thread_time()
                report = analyze(data, detector)
                cpu[name].append(1000 * (time.thread_time() - start))
                cell = cells[name][str(share)]
                cell["trials"] += 1
                cell["decided"] += report.rotation_degrees == turn
                cell["wrong"] += report.rotation_degrees not in (None, turn)
                marks += "+" if report.rotation_degrees == turn else "." if report.rotation_degrees is None else "X"
            print(f"{name_photo[:36]:36s} share {share:.2f} turn {turn:3d} {marks}", flush=True)
    dev = {name: {"trials": 0, "decided": 0, "wrong": 0} for name in configs if _dev_config(name)}
    for path in [p for p in photos if p.name not in NEGATIVES]:
        for turn, data in rotated_inputs(path).items():
            for name in dev:
                got = analyze(data, configs[name]).rotation_degrees
                dev[name]["trials"] += 1
                dev[name]["decided"] += got == turn
                dev[name]["wrong"] += got not in (None, turn)
    return {"canvas": list(CANVAS), "shares": list(FACE_SHARES), "turns": list(FACE_SIZE_TURNS),
            "photos": len(photos_used), "cells": cells, "dev_photos": dev,
            "cpu_ms_per_photo": {n: statistics.median(v) for n, v in cpu.items()},
            "load_average_before": load_before, "load_average_after": os.getloadavg()[0]}

def _dev_config(name: str) -> bool:
    """The searches also run on the dev photos as they are: the previous release's, the rule alone and the engine's."""
    return "previous release" in name or name.endswith(("engine)", "alone"))

def face_sizes_markdown(result: dict) -> str:
    shares = [str(s) for s in result["shares"]]
    h = min(result["canvas"])
    rows = []
    for name, by_share in result["cells"].items():
        total = sum(c["decided"] for c in by_share.values())
        trials = sum(c["trials"] for c in by_share.values())
        wrong = sum(c["wrong"] for c in by_share.values())
        rows.append([name, *[f"{by_share[s]['decided']}/{by_share[s]['trials']}" for s in shares],
                     f"{total}/{trials} ({100 * total / max(trials, 1):.1f}%)", wrong,
                     f"{result['cpu_ms_per_photo'][name]:.0f}"])
    names = list(result["cells"])
    engine = next(n for n in names if n.endswith("engine)"))
    previous = next(n for n in names if "previous release" in n)
    worse = [s for s in shares if result["cells"][engine][s]["decided"] < result["cells"][previous][s]["decided"]]
    dev = result["dev_photos"]
    if dev[engine]["decided"] < dev[previous]["decided"]:
        worse.append(f"the dev photos at native size ({dev[engine]['decided']} against {dev[previous]['decided']})")
    verdict = ("the engine decides at least as many trials as the previous release at every face size and on the "
               "dev photos at native size: **met**" if not worse else
               "the engine decides fewer trials than the previous release at face shares " + ", ".join(worse)
               + ": **not met**")
    return "\n".join([
        f"The paper's detector alone (Haar face + OpenCV's part cascades, text cue off) on faces of every size: the "
        f"{result['photos']} dev face photos with a YuNet face, each scaled so that its largest face is a given share "
        f"of the short side of a {result['canvas'][1]} x {h} photo (cut around the face, edge pixels repeated at the borders; "
        f"never enlarged more than 3x), turned {', '.join(map(str, result['turns']))} degrees, JPEG q90 (the engine "
        f"decodes it to <= 900 px). Cells: trials decided right / trials per face share (face width in the photo = "
        f"share x {h} px). CPU: median ms per photo (one thread, OpenCV single-threaded, decode included). "
        + load_note(result["load_average_before"], result["load_average_after"])
        + " CPU ms grow with the load: compare within the table.", "",
        md_table(["Haar search", *[f"{float(s):.2f} ({round(float(s) * h)} px)" for s in shares], "all", "wrong",
                  "CPU ms/photo"], rows), "",
        f"Faces never below the previous release: {verdict}.", "",
        "The same detector on the dev face photos as they are (native size, 4 turns, JPEG q95):", "",
        md_table(["Haar search", "decided", "wrong"], [[n, f"{c['decided']}/{c['trials']}", c["wrong"]]
                                                    for n, c in result["dev_photos"].items()])])


def main() -> int:
    parser = argparse.ArgumentParser(prog=prog(), description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a third of the photos")
    args = parser.parse_args()
    faces, yunet = dev_photos(), yunet_model()
    if faces is None or yunet is None:
        print("skipped: the face-size set needs $SWEEPCAST_DATA/faces/dev and the YuNet model beside the data")
        return 0
    photos = find_photos(faces)
    result = run_face_sizes(photos[::3] if args.quick else photos, yunet)
    publish("orientation_face_sizes", result, face_sizes_markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
