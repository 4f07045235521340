"""Where a photo's text is: the lines a text-detection network finds, before anything is read.

The text cue's gate. A DB text detector (Liao et al., *Real-time Scene Text Detection with Differentiable
Binarization*; PaddleOCR's multilingual PP-OCRv6 small model, shipped inside the ``rapidocr`` wheel and run with
onnxruntime) turns a small copy of the photo (``GATE_PIXELS`` pixels, tens of milliseconds) into a
probability map of text; its connected regions are text lines, each a rotated rectangle. A photo with no line costs
the gate alone; the lines of the others tell where to read and along which axis the text runs (a line is long along
its reading direction), so the reader (:mod:`workers.orientation.linereader`) reads a few line strips instead of
whole pages in four views.

Small print on a large page (a receipt on an A4 scan) is a few pixels tall at the gate's size: the map then shows it
as thin streaks. Where the first pass sees enough of them (``ZOOM_MIN_THIN``, ``ZOOM_THIN_SHARE``), the detector
looks again at their region at ``ZOOM_FACTOR`` times the resolution (:meth:`LineDetector.scan`).

The network sees what it was trained on: dark or light text on any background, in any of the four turns (it finds the
lines of a page turned 90 degrees as vertical lines), Latin, CJK and other scripts.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Callable, Literal

import cv2
import numpy as np

from workers.common.denormals import flushed_denormals
from workers.orientation.quantize import Precision, gate_model, one_core_session

Axis = Literal["h", "v"]
LoadImage = Callable[[float], tuple[np.ndarray, float]]
"""Given how many times larger than the gate's image an image of the same photo should be, the photo decoded that
large (or as large as it is) and the factor it actually has."""

GATE_PIXELS = 480 * 360
"""Pixels of the copy the gate's first pass looks at (a 4:3 photo at 480 x 360, a square one at 416 x 416, a long
receipt at 810 x 213). The detector's cost grows with the pixels (about 35 ms of one core for these, 160 ms for four
times as many, on the AMD EPYC of this project's benchmarks; 53 ms for these on an Intel Xeon); a pixel budget rather
than a long side keeps the lines of a long receipt as tall as a photo's (at 480 px on its long side, a receipt's lines
were 3 px tall and ran together)."""
GATE_MAX_SIDE = 1024
"""... and its long side at most this (px): a panorama or a till roll is not stretched into a thread."""
PROBABILITY_THRESHOLD = 0.3
"""A map pixel is text when its probability reaches this (DB's binarisation threshold, PaddleOCR's default)."""
LINE_MIN_SCORE = 0.6
"""A region is a line when its mean probability reaches this (PaddleOCR's box threshold is 0.5-0.6)."""
UNCLIP_RATIO = 1.6
"""DB's text kernels are shrunk lines: each rectangle is grown by ``area * ratio / perimeter`` on every side (the
paper's unclip; PaddleOCR's default ratio)."""
LINE_MIN_HEIGHT = 3.0
"""Least height (px of the detector's copy) of a line: thinner regions are rules, edges, or noise."""
LINE_MIN_ELONGATION = 2.0
"""A line's length is at least this many times its height; squarer regions (a single letter, a logo, a blob) carry
no reading direction."""
AXIS_TOLERANCE_DEG = 30.0
"""A line lies along the horizontal axis when its direction is within this of 0 degrees, along the vertical within
this of 90 degrees; lines between are left out (slanted text reads poorly, and tells no quarter turn)."""
ZOOM_MIN_THIN = 2
"""The gate looks again, closer, when its first pass found at least this many *thin* lines (elongated text regions
thinner than ``LINE_MIN_HEIGHT``: print too small for the copy) ..."""
ZOOM_THIN_SHARE = 0.25
"""... and they are at least this share of the lines it found (a page of small print, not a few thin strokes among
the lines of a sign)."""
ZOOM_BELOW_LINES = 3
"""The gate also looks again, closer, at the ink of a page when its first pass found fewer lines than this ..."""
PAPER_SHARE = 0.6
"""... and the photo is mostly blank paper: at least this share of its pixels within ``PAPER_TOLERANCE`` grey levels
of its paper white (its 95th percentile), which is at least ``PAPER_MIN_WHITE``. Small print sideways is what the
network finds worst at the gate's size (a receipt scanned on an A4 page, turned 90 degrees)."""
PAPER_TOLERANCE = 16
PAPER_MIN_WHITE = 180
INK_BELOW_WHITE = 40
"""A pixel of such a page is ink when it is this many grey levels darker than its paper white."""
INK_MIN_PROBABILITY = 0.1
"""... and when the first pass's map reaches at least this text probability somewhere in the page's ink: small print
shows there as text the network half saw (in the benchmarks' text trials, every page whose closer look found a line
had 0.35 or more; the receipt of this project's tests 0.46 sideways), a paper texture as nothing at all (0.02-0.06 on
the no-text set's papers, whose closer look cost 0.36 s each and found nothing). A third of DB's binarisation
threshold (``PROBABILITY_THRESHOLD``) keeps that margin."""
REFINE_BELOW_PX = 9.0
"""The gate looks again, closer, at the lines it found when their median height in its copy is under this (px): lines
of a few pixels run into each other (a receipt's close lines came out as blocks of two or three), and their
rectangles are too rough to cut strips from."""
REFINE_LINE_PX = 20.0
"""... at the scale that makes that median line this tall (px; the detector's best size), ..."""
REFINE_MAX_SIDE = 1280
"""... its copy of the lines' region at most this long (px)."""
LINE_HEIGHT_BAND = (0.6, 1.6)
"""The lines read first are those whose height is within this factor of the axis's median line height (a block of
merged lines, a title or a logo is not what a reading needs first)."""
ZOOM_FACTOR = 2.5
"""How much closer the second pass looks: the responding region at this many times the first pass's resolution,
its long side at most ``ZOOM_MAX_SIDE`` px."""
ZOOM_MAX_SIDE = 1120
"""Long side (px) of the second pass's copy at most (its cost about 4x the first pass's)."""
_MODEL_FILE = "PP-OCRv6_det_small.onnx"


@dataclass(frozen=True)
class TextLine:
    """One line of text: a rotated rectangle in pixels of the image the detector was given.

    ``center`` (x, y) px; ``direction`` the unit vector along the line, pointing right for a line along the horizontal
    axis (``axis`` "h") and down for one along the vertical (``axis`` "v"): the text reads that way or the opposite,
    which the reader tells; ``length`` and ``height`` px along and across it; ``score`` the mean text probability
    inside it (0-1)."""

    center: tuple[float, float]
    direction: tuple[float, float]
    length: float
    height: float
    score: float
    axis: Axis

    @property
    def quad(self) -> np.ndarray:
        """(4, 2) float32 corners: the strip's top-left, top-right, bottom-right, bottom-left when read along
        ``direction`` (its "top" lies to the left of the direction, as a page's top lies left of its lines)."""
        c = np.float32(self.center)
        u = np.float32(self.direction)
        v = np.float32((-u[1], u[0]))  # ``direction`` turned 90 degrees clockwise (y points down): across the line
        a, b = u * (self.length / 2), v * (self.height / 2)
        return np.stack([c - a - b, c + a - b, c + a + b, c - a + b]).astype(np.float32)

    def scaled(self, factor: float, offset: tuple[float, float] = (0.0, 0.0)) -> "TextLine":
        """The same line in an image ``factor`` times larger, shifted by ``offset`` (x, y px of that image)."""
        return TextLine((self.center[0] * factor + offset[0], self.center[1] * factor + offset[1]), self.direction,
                        self.length * factor, self.height * factor, self.score, self.axis)


@dataclass(frozen=True)
class LineScan:
    """What the gate found in one photo: its lines, in pixels of the grey image given to :meth:`LineDetector.scan`."""

    lines: tuple[TextLine, ...]
    zoomed: bool = False
    """Whether the second, closer pass ran (small print)."""
    thin: int = 0
    """Thin lines (small print) the first pass saw."""

    def on_axis(self, axis: Axis) -> list[TextLine]:
        """The lines along ``axis``: those of about the median height first (``LINE_HEIGHT_BAND``), longest and surest
        first, then the others."""
        lines = [ln for ln in self.lines if ln.axis == axis]
        if not lines:
            return []
        median = float(np.median([ln.height for ln in lines]))
        low, high = LINE_HEIGHT_BAND
        return sorted(lines, key=lambda ln: (not low * median <= ln.height <= high * median, -ln.score * ln.length))

    def axes(self) -> list[Axis]:
        """The axes that hold lines, the one with more (summed length) first."""
        totals = {a: sum(ln.length for ln in self.lines if ln.axis == a) for a in ("h", "v")}
        return [a for a in sorted(totals, key=lambda a: -totals[a]) if totals[a] > 0]


def model_path(name: str = _MODEL_FILE, what: str = "text detector") -> Path:
    """The ONNX file ``name`` inside the installed ``rapidocr`` package (default: the detector's; FileNotFoundError,
    naming ``what`` it is, when it is not there)."""
    path = Path(str(resources.files("rapidocr") / "models" / name))
    if not path.is_file():
        raise FileNotFoundError(f"the {what} model {path} is missing (reinstall rapidocr)")
    return path


class LineDetector:
    """The DB text-line detector on one core (callers run photos in parallel processes). Thread-safe: onnxruntime
    sessions may be run from several threads. ``precision``: the network in float (``float``), in 8-bit integers
    (``int8``: about 0.6-0.8x the CPU, a few lines fewer; :mod:`workers.orientation.quantize`), or in 8 bits where the
    CPU runs them fast (``auto``). ``model`` (a float ONNX file) replaces rapidocr's."""

    def __init__(self, model: Path | None = None, precision: Precision = "float") -> None:
        self.model = gate_model(model or model_path(), precision, lambda page: network_input(page, max(page.shape))[0])
        self._session = _grey_session(self.model.path)
        self._input = self._session.get_inputs()[0].name
        self._channels = int(self._session.get_inputs()[0].shape[1])

    def probability(self, gray: np.ndarray, side: int) -> tuple[np.ndarray, float]:
        """(text probability map (h, w) float32 in [0, 1], its scale relative to ``gray``) for ``gray`` ((H, W) uint8)
        resized so that its long side is ``side`` px (:func:`network_input`; the map cut back to the copy)."""
        x, (nh, nw) = network_input(gray, side, self._channels)
        with flushed_denormals():
            out = self._session.run(None, {self._input: x})[0][0, 0]
        return out[:nh, :nw], nw / gray.shape[1]

    def lines(self, gray: np.ndarray, side: int) -> tuple[list[TextLine], list[TextLine], float]:
        """(the lines in ``gray`` ((H, W) uint8), the thin ones (too small to keep), both in px of ``gray``; the
        scale of the detector's copy)."""
        found, thin, scale, _ = self._lines_and_map(gray, side)
        return found, thin, scale

    def _lines_and_map(self, gray: np.ndarray, side: int) -> tuple[list[TextLine], list[TextLine], float, np.ndarray]:
        """:meth:`lines`, and the probability map they came from (:meth:`probability`)."""
        prob, scale = self.probability(gray, side)
        lines, thin = lines_from_map(prob)
        return [ln.scaled(1.0 / scale) for ln in lines], [ln.scaled(1.0 / scale) for ln in thin], scale, prob

    def scan(self, gray: np.ndarray, load: LoadImage | None = None) -> LineScan:
        """The gate on ``gray`` ((H, W) uint8, the stored image or a reduced copy): its lines (px of ``gray``), with the
        second, closer pass over the region where small print shows (module docstring). ``load`` gives a larger decode
        of the same photo when the closer look needs more pixels than ``gray`` has (default: ``gray`` upscaled)."""
        found, thin, scale, prob = self._lines_and_map(gray, gate_side(gray.shape))
        load = load or upscaler(gray)
        if len(thin) >= ZOOM_MIN_THIN and len(thin) >= ZOOM_THIN_SHARE * len(found):
            region, closer, max_side = _region(thin, gray.shape), scale * ZOOM_FACTOR, ZOOM_MAX_SIDE
        elif (len(found) < ZOOM_BELOW_LINES and (ink := ink_region(gray)) is not None
              and _peak(prob, ink, scale) >= INK_MIN_PROBABILITY):
            region, closer, max_side = ink, scale * ZOOM_FACTOR, ZOOM_MAX_SIDE
        elif found and (small := _small_lines(found, scale)):
            region = _region(small, gray.shape)
            closer = scale * REFINE_LINE_PX / (scale * float(np.median([ln.height for ln in small])))
            max_side = REFINE_MAX_SIDE
        else:
            return LineScan(tuple(found), False, len(thin))
        closer_lines = self._closer(gray, region, closer, max_side, load)
        if closer_lines is None:
            return LineScan(tuple(found), False, len(thin))
        kept = [ln for ln in found if not _inside(ln, region)]
        return LineScan(tuple(kept + closer_lines), True, len(thin))

    def _closer(self, gray: np.ndarray, region: tuple[int, int, int, int], closer: float, max_side: int,
                load: LoadImage) -> list[TextLine] | None:
        """The lines of ``region`` (x0, y0, x1, y1 px of ``gray``) looked at ``closer`` times ``gray``'s resolution (its
        long side at most ``max_side`` px), in px of ``gray``; None when the region is too small to look at."""
        x0, y0, x1, y1 = region
        side = min(max_side, round(max(x1 - x0, y1 - y0) * closer))
        if side < 64:
            return None
        image, factor = (gray, 1.0) if closer <= 1.0 else load(closer)
        crop = image[round(y0 * factor):round(y1 * factor), round(x0 * factor):round(x1 * factor)]
        lines, _, _ = self.lines(crop, side)
        return [ln.scaled(1.0 / factor, (x0, y0)) for ln in lines]


def _grey_session(model: Path):
    """A one-core session of the gate's ``model`` made to take one grey channel
    (:func:`~workers.orientation.onnxshape.grey_input`: the page is grey, so its three channels were always equal; the
    first convolution then costs a third, about 2 % of the network), or of ``model`` as it is where its input cannot be
    folded (an 8-bit model)."""
    from workers.orientation.onnxshape import grey_input

    data = model.read_bytes()
    try:
        return one_core_session(grey_input(data))
    except ValueError:
        return one_core_session(data)


def network_input(gray: np.ndarray, side: int, channels: int = 3) -> tuple[np.ndarray, tuple[int, int]]:
    """(the network's input (1, ``channels``, H', W') float32 in [-1, 1], the copy's (h, w) px inside it) for ``gray``
    ((H, W) uint8) resized so that its long side is ``side`` px (one scale for both axes), padded with its edge to
    multiples of 32 px (the network's stride); its channels are the grey copy repeated (the model reads RGB, or one
    grey channel once folded: :func:`_grey_session`)."""
    h, w = gray.shape[:2]
    s = side / max(h, w)
    nh, nw = max(1, round(h * s)), max(1, round(w * s))
    small = cv2.resize(gray, (nw, nh), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
    ph, pw = -(-nh // 32) * 32, -(-nw // 32) * 32
    small = cv2.copyMakeBorder(small, 0, ph - nh, 0, pw - nw, cv2.BORDER_REPLICATE)
    x = (small.astype(np.float32) * (2.0 / 255.0) - 1.0)[None, None]  # the model's (x / 255 - 0.5) / 0.5
    return (np.ascontiguousarray(np.repeat(x, channels, axis=1)) if channels > 1 else x), (nh, nw)


def upscaler(gray: np.ndarray) -> LoadImage:
    """A :data:`LoadImage` that upscales ``gray`` itself (bicubic): for callers with no larger decode."""
    def load(factor: float) -> tuple[np.ndarray, float]:
        factor = max(1.0, factor)
        return cv2.resize(gray, None, fx=factor, fy=factor, interpolation=cv2.INTER_CUBIC), factor
    return load


def ink_region(gray: np.ndarray) -> tuple[int, int, int, int] | None:
    """Where the ink of a mostly blank page lies (x0, y0, x1, y1 px of ``gray``, (H, W) uint8), or None when ``gray``
    is not such a page (``PAPER_SHARE``): the 2nd to 98th percentile of the ink pixels' coordinates on a small copy,
    padded by a tenth."""
    s = min(1.0, 240 / max(gray.shape[:2]))
    small = cv2.resize(gray, None, fx=s, fy=s, interpolation=cv2.INTER_AREA) if s < 1 else gray
    white = float(np.percentile(small, 95))
    if white < PAPER_MIN_WHITE or float(np.mean(small >= white - PAPER_TOLERANCE)) < PAPER_SHARE:
        return None
    ys, xs = np.nonzero(small < white - INK_BELOW_WHITE)
    if len(xs) < 20:
        return None
    (x0, x1), (y0, y1) = np.percentile(xs, (2, 98)) / s, np.percentile(ys, (2, 98)) / s
    pad_x, pad_y = 0.1 * (x1 - x0) + 8, 0.1 * (y1 - y0) + 8
    h, w = gray.shape[:2]
    return (max(0, int(x0 - pad_x)), max(0, int(y0 - pad_y)), min(w, int(math.ceil(x1 + pad_x))),
            min(h, int(math.ceil(y1 + pad_y))))


def gate_side(shape: tuple[int, ...]) -> int:
    """The long side (px) of the gate's first copy of an image of ``shape``: ``GATE_PIXELS`` pixels, at most
    ``GATE_MAX_SIDE`` px long."""
    h, w = shape[:2]
    return min(GATE_MAX_SIDE, round(max(h, w) * math.sqrt(GATE_PIXELS / (h * w))))


def _small_lines(lines: list[TextLine], scale: float) -> list[TextLine]:
    """The lines of the axis with more lines when their median height in the detector's copy (``scale`` times the
    image) is under ``REFINE_BELOW_PX``; else none."""
    axis = max(("h", "v"), key=lambda a: sum(ln.axis == a for ln in lines))
    on_axis = [ln for ln in lines if ln.axis == axis]
    if not on_axis or float(np.median([ln.height for ln in on_axis])) * scale >= REFINE_BELOW_PX:
        return []
    return on_axis


def _peak(prob: np.ndarray, region: tuple[int, int, int, int], scale: float) -> float:
    """The highest text probability of ``prob`` (a map ``scale`` times its image) inside ``region`` (x0, y0, x1, y1 px
    of the image)."""
    x0, y0, x1, y1 = (int(v * scale) for v in region)
    inside = prob[y0:y1 + 1, x0:x1 + 1]
    return float(inside.max()) if inside.size else 0.0


def _inside(line: TextLine, box: tuple[int, int, int, int]) -> bool:
    x, y = line.center
    return box[0] <= x < box[2] and box[1] <= y < box[3]


def _region(lines: list[TextLine], shape: tuple[int, ...]) -> tuple[int, int, int, int]:
    """The bounding box (x0, y0, x1, y1 px of an image of ``shape``) of ``lines``, padded by a fifth of its size."""
    corners = np.concatenate([ln.quad for ln in lines])
    (x0, y0), (x1, y1) = corners.min(axis=0), corners.max(axis=0)
    pad_x, pad_y = 0.2 * (x1 - x0) + 8, 0.2 * (y1 - y0) + 8
    h, w = shape[:2]
    return (max(0, int(x0 - pad_x)), max(0, int(y0 - pad_y)), min(w, int(math.ceil(x1 + pad_x))),
            min(h, int(math.ceil(y1 + pad_y))))


def lines_from_map(prob: np.ndarray) -> tuple[list[TextLine], list[TextLine]]:
    """(the text lines, the thin ones) of a probability map ((h, w) float32 in [0, 1]), in map px: DB's
    post-processing (threshold, connected regions, their mean probability, the minimum-area rectangle grown by the
    unclip distance), keeping the elongated regions that run along one of the image's axes; those thinner than
    ``LINE_MIN_HEIGHT`` before growing are the thin ones (small print at this scale)."""
    binary = (prob >= PROBABILITY_THRESHOLD).astype(np.uint8)
    contours, _ = cv2.findContours(binary, cv2.RETR_LIST, cv2.CHAIN_APPROX_SIMPLE)
    lines, thin = [], []
    for contour in contours:
        if len(contour) < 3:
            continue
        (cx, cy), (w, h), angle = cv2.minAreaRect(contour)
        if min(w, h) < 1:
            continue
        score = _mean_inside(prob, contour)
        if score < LINE_MIN_SCORE:
            continue
        if min(w, h) < LINE_MIN_HEIGHT:
            line = _line(((cx, cy), (max(w, 1.0), max(h, 1.0)), angle), score, min_height=0.0)
            if line is not None and line.length >= 3 * LINE_MIN_HEIGHT:
                thin.append(line)
            continue
        grow = w * h * UNCLIP_RATIO / (2 * (w + h))
        line = _line(((cx, cy), (w + 2 * grow, h + 2 * grow), angle), score)
        if line is not None:
            lines.append(line)
    return lines, thin


def _mean_inside(prob: np.ndarray, contour: np.ndarray) -> float:
    x, y, w, h = cv2.boundingRect(contour)
    mask = np.zeros((h, w), np.uint8)
    cv2.drawContours(mask, [contour - np.array([x, y])], -1, 1, thickness=-1)
    return float(cv2.mean(prob[y:y + h, x:x + w], mask=mask)[0])


def _line(rect: tuple, score: float, min_height: float = LINE_MIN_HEIGHT) -> TextLine | None:
    """A :class:`TextLine` from an OpenCV rotated rectangle ((cx, cy), (w, h), angle); None when it is too thin, too
    square, or slanted between the axes."""
    (cx, cy), (w, h), angle = rect
    if h > w:  # OpenCV's w runs along ``angle``; the line runs along its long side
        w, h, angle = h, w, angle + 90.0
    if h < min_height or w < LINE_MIN_ELONGATION * h:
        return None
    ux, uy = math.cos(math.radians(angle)), math.sin(math.radians(angle))
    folded = abs(math.degrees(math.atan2(uy, ux))) % 180.0
    if min(folded, 180.0 - folded) <= AXIS_TOLERANCE_DEG:
        axis: Axis = "h"
        sign = 1.0 if ux > 0 else -1.0
    elif abs(folded - 90.0) <= AXIS_TOLERANCE_DEG:
        axis = "v"
        sign = 1.0 if uy > 0 else -1.0
    else:
        return None
    return TextLine((float(cx), float(cy)), (sign * ux, sign * uy), float(w), float(h), score, axis)


_LOCK = threading.Lock()


@lru_cache(maxsize=3)
def _shared(precision: Precision) -> LineDetector:
    return LineDetector(precision=precision)


def get_line_detector(precision: Precision | None = None) -> LineDetector:
    """The process's line detector of this ``precision`` (default: the ``orientation_gate_precision`` setting), its
    model loaded once."""
    if precision is None:
        from workers.settings import worker_settings

        precision = worker_settings().orientation_gate_precision
    with _LOCK:
        return _shared(precision)
