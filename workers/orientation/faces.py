"""Whole-face detectors run on one view: Haar (the paper's) and YuNet (optional, stronger).

Both search a shrunk copy of the view (faces smaller than the search's smallest window there are lost; the facial
parts are searched later in the full-resolution view) and return candidates in view pixels: YuNet a copy
``scan_size`` px on its long side, Haar a copy whose short side follows the photo (:class:`ShortSideScan`). Instances hold OpenCV state and are not thread-safe.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from workers.orientation.geometry import Box
from workers.orientation.parts import load_cascade

HAAR_FACE_CASCADE = Path(cv2.data.haarcascades) / "haarcascade_frontalface_alt.xml"
"""The whole-face cascade the paper used (frontalface_alt)."""


@dataclass(frozen=True)
class Candidate:
    """A face candidate in one view: box (x, y, w, h) in view px, YuNet score (None for Haar)."""

    box: Box
    score: float | None


def _shrink(view: np.ndarray, scan_size: int) -> tuple[np.ndarray, float]:
    """``view`` resized so its long side is at most ``scan_size``, and the factor applied (<= 1)."""
    s = min(1.0, scan_size / max(view.shape[:2]))
    if s == 1.0:
        return view, 1.0
    size = (max(1, round(view.shape[1] * s)), max(1, round(view.shape[0] * s)))
    return cv2.resize(view, size, interpolation=cv2.INTER_AREA), s


@dataclass(frozen=True)
class ShortSideScan:
    """The Haar face search's scan that follows the photo: the smallest face searched is ``smallest_face`` of the
    view's short side, and the scan is scaled so that this face measures ``face_px`` in it (never enlarged). The
    pyramid runs from ``face_px`` up to the scan's short side (a face filling the photo).

    So the scan's short side is ``face_px / smallest_face`` whatever the photo's size and shape (a panorama keeps its
    faces' size, where a long-side scan shrank them), and a face keeps its share of the photo's short side in pixels
    of the scan."""

    smallest_face: float
    face_px: int

    def plan(self, height: int, width: int) -> tuple[float, int, int]:
        """(scale of the scan, smallest and largest face searched in scan px) for a ``height`` x ``width`` view."""
        short = min(height, width)
        s = min(1.0, self.face_px / (self.smallest_face * short))
        return s, self.face_px, max(self.face_px, int(short * s))


@dataclass(frozen=True)
class LongSideScan:
    """The previous releases' scan: the view shrunk to ``scan_size`` on its long side, faces from ``min_size`` px
    up (benchmarks compare the rule above with it)."""

    scan_size: int
    min_size: int

    def plan(self, height: int, width: int) -> tuple[float, int, int]:
        s = min(1.0, self.scan_size / max(height, width))
        return s, self.min_size, 0


class HaarFaceFinder:
    """Viola-Jones frontal-face detection (``detectMultiScale`` on the histogram-equalised scan)."""

    def __init__(self, scan: ShortSideScan | LongSideScan, scale_factor: float, min_neighbors: int,
                 cascade: Path = HAAR_FACE_CASCADE) -> None:
        self._cascade = load_cascade(cascade)
        self.scan = scan
        self.scale_factor = scale_factor
        self.min_neighbors = min_neighbors

    def find(self, view: np.ndarray, within: Sequence[Box] | None = None) -> list[Candidate]:
        """Faces in ``view`` ((H, W) uint8 grey), boxes in view px; with ``within`` (boxes in view px), only the
        faces inside those regions: the scan is planned and equalised as for the whole view, and searched only there
        (windows wholly inside a region give the same detections)."""
        s, smallest, largest = self.scan.plan(*view.shape[:2])
        if s < 1.0:
            size = (max(1, round(view.shape[1] * s)), max(1, round(view.shape[0] * s)))
            scan = cv2.resize(view, size, interpolation=cv2.INTER_AREA)
            s = size[0] / view.shape[1]
        else:
            scan = view
        scan = cv2.equalizeHist(scan)
        regions = [(0, 0, scan.shape[1], scan.shape[0])] if within is None else [
            _scaled_region(box, s, scan.shape) for box in within]
        found = []
        for x0, y0, x1, y1 in regions:
            if x1 - x0 < smallest or y1 - y0 < smallest:
                continue
            boxes = self._cascade.detectMultiScale(scan[y0:y1, x0:x1], scaleFactor=self.scale_factor,
                                                   minNeighbors=self.min_neighbors, minSize=(smallest, smallest),
                                                   maxSize=(largest, largest))
            found += [Candidate(((x + x0) / s, (y + y0) / s, w / s, h / s), None) for x, y, w, h in boxes]
        return found


def _scaled_region(box: Box, s: float, shape: tuple[int, ...]) -> tuple[int, int, int, int]:
    """``box`` (view px) in the scan scaled by ``s`` (clipped to ``shape``) as (x0, y0, x1, y1) ints."""
    x, y, w, h = box
    return (max(0, int(x * s)), max(0, int(y * s)), min(shape[1], int(np.ceil((x + w) * s))),
            min(shape[0], int(np.ceil((y + h) * s))))


class YuNetFaceFinder:
    """OpenCV's YuNet CNN face detector (``cv2.FaceDetectorYN``) on a 3-channel copy of the grey scan."""

    def __init__(self, model: Path, score_floor: float = 0.5) -> None:
        model = Path(model)
        if not model.is_file():
            raise FileNotFoundError(f"YuNet model not found: {model}")
        try:
            self._net = cv2.FaceDetectorYN.create(str(model), "", (320, 320), score_floor, 0.3, 5000)
        except cv2.error as exc:
            raise FileNotFoundError(f"cannot load the YuNet model {model}: {exc.err or exc}") from None

    def find(self, view: np.ndarray, scan_size: int) -> list[Candidate]:
        """Faces in ``view`` ((H, W) uint8 grey), searched on a copy at most ``scan_size`` px on its long
        side, with their scores in [0, 1]; boxes in view px."""
        scan, s = _shrink(view, scan_size)
        self._net.setInputSize((scan.shape[1], scan.shape[0]))
        _, rows = self._net.detect(cv2.cvtColor(scan, cv2.COLOR_GRAY2BGR))
        if rows is None:
            return []
        return [Candidate(tuple(float(v) / s for v in row[:4]), float(row[14])) for row in rows]
