"""Whole-face detectors run on one view: Haar (the paper's) and YuNet (optional, stronger).

Both search a shrunk copy of the view (faces smaller than the search's smallest window there are lost; the facial
parts are searched later in the full-resolution view) and return candidates in view pixels: YuNet a copy
``scan_size`` px on its long side, Haar a copy whose short side follows the photo (:class:`ShortSideScan`). The Haar
instances hold OpenCV state and are not thread-safe.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from workers.common.denormals import flushed_denormals
from workers.orientation.geometry import Box, rotate_view
from workers.orientation.parts import load_cascade

HAAR_FACE_CASCADE = Path(cv2.data.haarcascades) / "haarcascade_frontalface_alt.xml"
"""The whole-face cascade the paper used (frontalface_alt)."""


@dataclass(frozen=True)
class Region:
    """Where a face search looks: ``box`` (x, y, w, h) px, and the least and greatest side (px) of the faces it looks
    for there (``sides``)."""

    box: Box
    sides: tuple[float, float]


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

    def find(self, view: np.ndarray, within: Sequence[Region] | None = None) -> list[Candidate]:
        """Faces in ``view`` ((H, W) uint8 grey), boxes in view px; with ``within``, only the faces inside each
        region's box (view px) whose side is within its ``sides`` (view px): the scan is planned and equalised as for
        the whole view, and searched only there, at the pyramid's scales of those sides widened by one step (a
        window wholly inside a region, at a scale searched, gives the same detection; the step keeps the neighbours
        a detection at the edge of the range is grouped with)."""
        s, smallest, largest = self.scan.plan(*view.shape[:2])
        if s < 1.0:
            size = (max(1, round(view.shape[1] * s)), max(1, round(view.shape[0] * s)))
            scan = cv2.resize(view, size, interpolation=cv2.INTER_AREA)
            s = size[0] / view.shape[1]
        else:
            scan = view
        scan = cv2.equalizeHist(scan)
        searches = [((0, 0, scan.shape[1], scan.shape[0]), smallest, largest)] if within is None else [
            self._scaled(region, s, scan.shape, smallest, largest) for region in within]
        found = []
        for (x0, y0, x1, y1), least, most in searches:
            if x1 - x0 < least or y1 - y0 < least or (most and least > most):
                continue
            boxes = self._cascade.detectMultiScale(scan[y0:y1, x0:x1], scaleFactor=self.scale_factor,
                                                   minNeighbors=self.min_neighbors, minSize=(least, least),
                                                   maxSize=(most, most))
            found += [Candidate(((x + x0) / s, (y + y0) / s, w / s, h / s), None) for x, y, w, h in boxes]
        return found

    def _scaled(self, region: Region, s: float, shape: tuple[int, ...], smallest: int,
                largest: int) -> tuple[tuple[int, int, int, int], int, int]:
        """((x0, y0, x1, y1), least and greatest face side) of ``region`` in the scan scaled by ``s`` (``largest`` 0:
        no greatest side)."""
        lo, hi = region.sides
        least = max(smallest, int(lo * s / self.scale_factor))
        most = int(np.ceil(hi * s * self.scale_factor))
        return _scaled_region(region.box, s, shape), least, min(most, largest) if largest else most


def _scaled_region(box: Box, s: float, shape: tuple[int, ...]) -> tuple[int, int, int, int]:
    """``box`` (view px) in the scan scaled by ``s`` (clipped to ``shape``) as (x0, y0, x1, y1) ints."""
    x, y, w, h = box
    return (max(0, int(x * s)), max(0, int(y * s)), min(shape[1], int(np.ceil((x + w) * s))),
            min(shape[0], int(np.ceil((y + h) * s))))


YUNET_STRIDES = (8, 16, 32)
"""The strides (px) of YuNet's three output grids; its input is padded to a multiple of the largest."""
YUNET_NMS_IOU = 0.3
"""Overlap (IoU) above which the weaker of two YuNet boxes is dropped (OpenCV's ``FaceDetectorYN`` default)."""


class YuNetFaceFinder:
    """The YuNet CNN face detector (Wu et al., 2023; OpenCV zoo's ``face_detection_yunet_2023mar.onnx``) run with
    onnxruntime on one core, at the size of the copy it is given.

    The model file declares a fixed 640 x 640 input, but its graph has no fixed size (its reshapes flatten the
    grids, its upsampling uses scales): the input's size is made free before the session is built, so a 320 x 240
    copy costs what its pixels cost. onnxruntime runs it in about half the CPU of OpenCV's ``FaceDetectorYN``
    (``benchmarks/orientation_text.py``), with the same detections: the outputs are decoded as OpenCV decodes them
    (score = sqrt(cls x obj), boxes from each grid cell, then non-maximum suppression)."""

    def __init__(self, model: Path, score_floor: float = 0.5) -> None:
        self._session = _yunet_session(Path(model))
        self._outputs = [o.name for o in self._session.get_outputs()]
        self._input = self._session.get_inputs()[0].name
        self.score_floor = score_floor

    def find_turned(self, gray: np.ndarray, scan_size: int, rotations: Sequence[int]) -> dict[int, list[Candidate]]:
        """The faces in each view ``rotate_view(gray, r)`` (``gray`` (H, W) uint8) for ``r`` in ``rotations``,
        searched on a copy at most ``scan_size`` px on its long side, with their scores in [0, 1]; boxes in view px.
        One copy is shrunk, then turned (the turn of a shrunk copy is the shrunk copy of the turn)."""
        scan, s = _shrink(gray, scan_size)
        found = {}
        for rotation in rotations:
            boxes, scores = self.detect(rotate_view(scan, rotation))
            found[rotation] = [Candidate(tuple(float(v) / s for v in box), float(score))
                               for box, score in zip(boxes, scores)]
        return found

    def detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(boxes (n, 4) float32 x, y, w, h px of ``gray``, scores (n,) float32 in [0, 1], best first) of the faces
        YuNet finds in ``gray`` ((H, W) uint8) scoring at least ``score_floor``."""
        h, w = gray.shape[:2]
        step = YUNET_STRIDES[-1]
        ph, pw = -(-h // step) * step, -(-w // step) * step
        padded = cv2.copyMakeBorder(gray, 0, ph - h, 0, pw - w, cv2.BORDER_CONSTANT, value=0)
        x = padded.astype(np.float32)[None, None]  # one grey channel (_yunet_session)
        with flushed_denormals():
            out = dict(zip(self._outputs, self._session.run(self._outputs, {self._input: x})))
        found = [_decode_grid(out, stride, pw // stride, self.score_floor) for stride in YUNET_STRIDES]
        boxes = np.concatenate([b for b, _ in found])
        scores = np.concatenate([s for _, s in found])
        if len(scores) > 1:  # OpenCV's suppression, on its integer boxes
            keep = np.asarray(cv2.dnn.NMSBoxes(boxes.astype(np.int32).tolist(), scores.tolist(), self.score_floor,
                                               YUNET_NMS_IOU), dtype=np.int64).reshape(-1)
            boxes, scores = boxes[keep], scores[keep]
        return boxes, scores


def _decode_grid(out: dict[str, np.ndarray], stride: int, cols: int,
                 floor: float) -> tuple[np.ndarray, np.ndarray]:
    """(boxes (n, 4) x, y, w, h px, scores (n,)) of the cells of YuNet's ``stride`` grid (``cols`` cells a row)
    scoring at least ``floor``: a cell's box is centred at (cell + offset) x stride, its size exp(size) x stride."""
    cls = out[f"cls_{stride}"][0, :, 0]
    if not len(cls) or float(cls.max()) < floor * floor * (1 - 1e-6):  # score <= sqrt(cls): none can reach the floor
        return np.zeros((0, 4), np.float32), np.zeros(0, np.float32)
    score = np.sqrt(np.clip(cls, 0, 1) * np.clip(out[f"obj_{stride}"][0, :, 0], 0, 1))
    cells = np.flatnonzero(score >= floor)
    pred = out[f"bbox_{stride}"][0][cells]
    cx = (cells % cols + pred[:, 0]) * stride
    cy = (cells // cols + pred[:, 1]) * stride
    w, h = np.exp(pred[:, 2]) * stride, np.exp(pred[:, 3]) * stride
    return np.stack([cx - w / 2, cy - h / 2, w, h], axis=1).astype(np.float32), score[cells]


def _ort_load_errors() -> tuple[type[Exception], ...]:
    """What onnxruntime raises for a model it cannot load (its own exception types, not RuntimeError's)."""
    from onnxruntime.capi import onnxruntime_pybind11_state as state

    names = ("Fail", "InvalidArgument", "NoSuchFile", "NoModel", "InvalidProtobuf", "InvalidGraph", "NotImplemented",
             "RuntimeException")
    return tuple(getattr(state, n) for n in names if isinstance(getattr(state, n, None), type))


def _yunet_session(model: Path):
    """An onnxruntime session (one thread) of the YuNet ``model`` with its input's height and width made free and its
    three colour channels folded into one grey channel (:func:`~workers.orientation.onnxshape.grey_input`: the
    detector is given grey photos, so the three channels were always equal). Raises FileNotFoundError when the file is
    missing or is not a YuNet model."""
    from workers.orientation.onnxshape import free_input_size, grey_input
    from workers.orientation.quantize import one_core_session

    if not model.is_file():
        raise FileNotFoundError(f"YuNet model not found: {model}")
    try:
        session = one_core_session(grey_input(free_input_size(model.read_bytes(), {2: "height", 3: "width"})))
    except (ValueError, RuntimeError, *_ort_load_errors()) as exc:
        raise FileNotFoundError(f"cannot load the YuNet model {model}: {exc}") from None
    names = {o.name for o in session.get_outputs()}
    if not {f"{k}_{s}" for k in ("cls", "obj", "bbox") for s in YUNET_STRIDES} <= names:
        raise FileNotFoundError(f"cannot load the YuNet model {model}: its outputs are not YuNet's ({sorted(names)})")
    return session
