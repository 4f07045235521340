"""Facial-part detection inside a face and the geometric test of the paper (section II-B, Fig. 4).

A face candidate is cut out of its view, resampled to a ``PART_CROP`` square, and each part
cascade (eyes, nose, mouth) searches the band of the face where that part can be. The parts
count only in a plausible arrangement for an upright face: two eyes in the upper half, roughly
level, apart and on either side of the middle; a nose centred below the eye line; a mouth
centred below the eyes. The face is accepted when at least ``min_parts`` parts are arranged so.

Two part sets exist: the cascades shipped with OpenCV (eyes from four cascades, the mouth from
the smile cascade) and the paper's own ``haarcascade_mcs_*`` set (eyes, nose, mouth), which is
licensed for non-commercial use only and therefore only loaded from a path given at run time.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

PART_CROP = 128
"""Side (px) of the square a face is resampled to before its parts are searched."""

# Search bands as fractions of the crop height: (top, bottom).
_EYE_BAND = (0.0, 0.6)
_NOSE_BAND = (0.25, 0.85)
_MOUTH_BAND = (0.5, 1.0)
# Sizes (px in the crop) a part may have: (min w, min h), (max w, max h).
_EYE_SIZE = ((12, 12), (60, 60))
_NOSE_SIZE = ((16, 14), (60, 60))
_MOUTH_SIZE = ((24, 12), (100, 60))


@dataclass(frozen=True)
class PartSpec:
    """Which cascade files find each part, and how many parts must agree to accept a face."""

    eyes: tuple[Path, ...]
    nose: tuple[Path, ...]
    mouth: tuple[Path, ...]
    min_parts: int

    @staticmethod
    def opencv() -> PartSpec:
        """The cascades in ``cv2.data.haarcascades``: an eye pair and a mouth (smile cascade) below it."""
        root = Path(cv2.data.haarcascades)
        # in the order they are tried (the cheapest first; each runs only while no eye pair is found)
        eyes = ("lefteye_2splits", "righteye_2splits", "eye", "eye_tree_eyeglasses")
        return PartSpec(
            eyes=tuple(root / f"haarcascade_{name}.xml" for name in eyes),
            nose=(),
            mouth=(root / "haarcascade_smile.xml",),
            min_parts=2,
        )

    @staticmethod
    def mcs(folder: Path) -> PartSpec:
        """The paper's cascades (Castrillon-Santana, CC BY-NC 4.0): two of eyes, nose, mouth."""
        folder = Path(folder)
        return PartSpec(
            eyes=(folder / "haarcascade_mcs_lefteye.xml", folder / "haarcascade_mcs_righteye.xml"),
            nose=(folder / "haarcascade_mcs_nose.xml",),
            mouth=(folder / "haarcascade_mcs_mouth.xml",),
            min_parts=2,
        )


def load_cascade(path: Path) -> cv2.CascadeClassifier:
    """A Haar cascade from an XML file; FileNotFoundError when it is missing or unreadable."""
    cascade = cv2.CascadeClassifier(str(path))
    if cascade.empty():
        raise FileNotFoundError(f"cannot load the Haar cascade {path}")
    return cascade


def face_crop(view: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray | None:
    """The square around ``box`` (x, y, w, h; view px) cut from grey ``view`` and resampled to
    (PART_CROP, PART_CROP) uint8; None when less than 8 px of it lie inside the view."""
    x, y, w, h = box
    side = max(w, h)
    cx, cy = x + w / 2, y + h / 2
    x0, y0 = max(0, int(round(cx - side / 2))), max(0, int(round(cy - side / 2)))
    x1, y1 = min(view.shape[1], int(round(cx + side / 2))), min(view.shape[0], int(round(cy + side / 2)))
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None
    patch = view[y0:y1, x0:x1]
    interp = cv2.INTER_AREA if patch.shape[0] > PART_CROP else cv2.INTER_LINEAR
    return cv2.resize(patch, (PART_CROP, PART_CROP), interpolation=interp)


class PartVerifier:
    """Finds facial parts in a face crop and tests their arrangement. Not thread-safe (OpenCV state)."""

    def __init__(self, spec: PartSpec) -> None:
        self.min_parts = spec.min_parts
        self._eyes = [load_cascade(p) for p in spec.eyes]
        self._nose = [load_cascade(p) for p in spec.nose]
        self._mouth = [load_cascade(p) for p in spec.mouth]

    def parts(self, crop: np.ndarray) -> tuple[str, ...]:
        """The parts ("eyes", "nose", "mouth") found in a plausible upright arrangement in ``crop``
        ((PART_CROP, PART_CROP) uint8 grey, the face supposedly upright). Once fewer than ``min_parts``
        can be found, the parts left are not searched (the face is rejected either way)."""
        found: list[str] = []
        pair = self._eye_pair(crop)
        if pair is not None:
            found.append("eyes")
        eye_line = (pair[0][1] + pair[1][1]) / 2 if pair is not None else 0.4 * PART_CROP
        rest = [(name, cascades, band, size, ok) for name, cascades, band, size, ok in (
            ("nose", self._nose, _NOSE_BAND, _NOSE_SIZE, _nose_ok),
            ("mouth", self._mouth, _MOUTH_BAND, _MOUTH_SIZE, _mouth_ok)) if cascades]
        for i, (name, cascades, band, size, ok) in enumerate(rest):
            if len(found) + len(rest) - i < self.min_parts:
                break  # rejected whatever the parts left say: not searched
            if ok(_centres(cascades, crop, band, size, neighbours=3), eye_line):
                found.append(name)
        return tuple(found)

    def _eye_pair(self, crop: np.ndarray) -> tuple[tuple[float, float], tuple[float, float]] | None:
        """The first plausible eye pair among the detections of the eye cascades run so far, in turn (the
        cheapest first): the later cascades run only while no pair is found (each costs a few ms a face)."""
        centres: list[tuple[float, float]] = []
        for cascade in self._eyes:
            centres += _centres([cascade], crop, _EYE_BAND, _EYE_SIZE, neighbours=2)
            pair = _eye_pair(centres)
            if pair is not None:
                return pair
        return None

    def accepts(self, parts: tuple[str, ...]) -> bool:
        return len(parts) >= self.min_parts


def _centres(cascades: list[cv2.CascadeClassifier], crop: np.ndarray, band: tuple[float, float],
             size: tuple[tuple[int, int], tuple[int, int]], neighbours: int) -> list[tuple[float, float]]:
    """Centres (x, y; crop px) of every detection of ``cascades`` inside the horizontal ``band``."""
    top, bottom = int(band[0] * PART_CROP), int(band[1] * PART_CROP)
    roi = crop[top:bottom]
    centres = []
    for cascade in cascades:
        boxes = cascade.detectMultiScale(roi, scaleFactor=1.1, minNeighbors=neighbours,
                                         minSize=size[0], maxSize=size[1])
        centres += [(x + w / 2, top + y + h / 2) for x, y, w, h in boxes]
    return centres


def _eye_pair(centres: list[tuple[float, float]]) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """Two eye centres in the upper half, level within 0.12, 0.2-0.65 apart, either side of the middle."""
    s = PART_CROP
    candidates = [c for c in centres if 0.1 * s < c[1] < 0.55 * s]
    for a, b in itertools.combinations(candidates, 2):
        left, right = (a, b) if a[0] <= b[0] else (b, a)
        if (0.2 * s <= right[0] - left[0] <= 0.65 * s and abs(right[1] - left[1]) <= 0.12 * s
                and left[0] < 0.5 * s < right[0]):
            return left, right
    return None


def _nose_ok(centres: list[tuple[float, float]], eye_line: float) -> bool:
    s = PART_CROP
    return any(abs(x - 0.5 * s) < 0.15 * s and eye_line + 0.05 * s < y < 0.8 * s for x, y in centres)


def _mouth_ok(centres: list[tuple[float, float]], eye_line: float) -> bool:
    s = PART_CROP
    return any(abs(x - 0.5 * s) < 0.2 * s and y > max(0.6 * s, eye_line + 0.15 * s) for x, y in centres)
