"""Whole-face detectors run on one view: Haar (the paper's) and YuNet (optional, stronger).

Both search a copy of the view shrunk to ``scan_size`` on its long side (faces smaller than the
search's smallest window there are lost; the facial parts are searched later in the full-resolution view) and return
candidates in view pixels. Instances hold OpenCV state and are not thread-safe.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

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


class HaarFaceFinder:
    """Viola-Jones frontal-face detection (``detectMultiScale`` on the histogram-equalised scan)."""

    def __init__(self, scan_size: int, scale_factor: float, min_neighbors: int, min_size: int,
                 cascade: Path = HAAR_FACE_CASCADE) -> None:
        self._cascade = load_cascade(cascade)
        self.scan_size = scan_size
        self.scale_factor = scale_factor
        self.min_neighbors = min_neighbors
        self.min_size = min_size

    def find(self, view: np.ndarray) -> list[Candidate]:
        """Faces in ``view`` ((H, W) uint8 grey), boxes in view px."""
        scan, s = _shrink(view, self.scan_size)
        boxes = self._cascade.detectMultiScale(cv2.equalizeHist(scan), scaleFactor=self.scale_factor,
                                               minNeighbors=self.min_neighbors,
                                               minSize=(self.min_size, self.min_size))
        return [Candidate((x / s, y / s, w / s, h / s), None) for x, y, w, h in boxes]


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
