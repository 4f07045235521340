"""What each photo costs and what is decided, by class (section orientation_text; issue 54).

Faces, text, neither faces nor text: the text photos of ``$SWEEPCAST_DATA/orientation/text`` and Leptonica's pages,
the no-text set of :mod:`benchmarks._notext`; this checkout beside the previous release, each engine in a process of
its own, and the text-line gate's recall and cost (:mod:`benchmarks._orientation_cost`, which measures it).

Run: ``python -m benchmarks.orientation_text [--quick] [--previous-turns 1|4]`` from the repository root (about 25
minutes on 2 cores).
"""
from __future__ import annotations

import argparse
import os
import sys

from benchmarks._orientation_cost import measure
from benchmarks._orientation_photos import dev_photos, yunet_model
from benchmarks._report import prog, publish
from benchmarks._timing import load_note
from workers.common.datasets import data_root


def main() -> int:
    parser = argparse.ArgumentParser(prog=prog(), description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a share of each class's photos")
    parser.add_argument("--previous-turns", type=int, choices=(1, 4), default=1,
                        help="the previous release reads the no-text images at 1 turn (90 degrees; default: it costs "
                             "seconds a photo) or at all 4")
    args = parser.parse_args()
    if dev_photos() is None:
        print(f"skipped: no face photos at {data_root() / 'faces' / 'dev'} (set SWEEPCAST_DATA)")
        return 0
    yunet = yunet_model()
    if yunet is None:
        print("note: no YuNet model beside the data; yunet and combined are not measured")
    load_before = os.getloadavg()[0]
    results, markdown = measure(args, yunet)
    results["load_average"] = [load_before, os.getloadavg()[0]]
    publish("orientation_text", results, markdown + "\n\n" + load_note(load_before, os.getloadavg()[0]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
