"""A rehearsal of the orientation engine on a page it makes itself, for a worker process that has time before its first
photo (a prepared Ray worker, :mod:`workers.prewarm`).

Building the engine loads its networks and cascades, but the text cue sets up more on its first text photo: a
Tesseract object per language and thread (English, and the script detection), the line reader's and the gate's first
runs. That cost 0.1-0.2 s of CPU in the first text photo of each worker process (0.89 s against 0.68 s for the same
photo again, measured 2026-12-07 on the library of ``benchmarks/orientation_library.py``), paid in every worker during
the first library after a start. A rehearsal pays it beforehand: a page of English lines, drawn here and turned a
quarter, analysed as a photo is.
"""
from __future__ import annotations

import cv2
import numpy as np

from workers.orientation.detect import OrientationDetector
from workers.orientation.orient import OrientationReport, analyze

LINES = ("The quick brown fox jumps over", "the lazy dog while the small", "children watch from the garden",
         "and their mother reads a letter", "about the weather in the north")
"""The page's text: dictionary words, enough of them for the cue to decide (so every step of the cue runs)."""


def rehearsal_page() -> bytes:
    """A JPEG (1200 x 900 px before its turn) of :data:`LINES` in dark type on white, turned 90 degrees clockwise:
    upright after a 270-degree clockwise turn."""
    page = np.full((900, 1200, 3), 255, np.uint8)
    for k, line in enumerate(LINES):
        cv2.putText(page, line, (60, 140 + 120 * k), cv2.FONT_HERSHEY_SIMPLEX, 1.6, (20, 20, 20), 3, cv2.LINE_AA)
    ok, jpeg = cv2.imencode(".jpg", cv2.rotate(page, cv2.ROTATE_90_CLOCKWISE), [cv2.IMWRITE_JPEG_QUALITY, 90])
    if not ok:
        raise RuntimeError("OpenCV could not encode the rehearsal page")
    return jpeg.tobytes()


def rehearse(detector: OrientationDetector) -> OrientationReport:
    """Analyse :func:`rehearsal_page` with ``detector`` on this thread (what a photo's analysis sets up the first
    time is then ready for the photos this thread analyses); its report."""
    return analyze(rehearsal_page(), detector, filename="rehearsal.jpg")
