"""The second cue: which way is up from text, by Tesseract's orientation and script detection (OSD).

Faces come first (the paper); when they decide nothing, the photo's text may. Tesseract's OSD
(``tesseract IMAGE stdout --psm 0``, Debian packages ``tesseract-ocr`` and ``tesseract-ocr-osd``)
classifies up to a few hundred character blobs in each of the four orientations and reports the
clockwise turn that makes the page upright, with a confidence. It is optional: without the binary
or its ``osd`` data the engine works on faces alone and says so (:func:`text_status`).

The rule stays the paper's: a wrong turn is far worse than no answer. OSD's known failure modes,
and what guards each:

- *too few characters*: OSD refuses pages with fewer than ``min_characters_to_try`` blobs
  ("Too few characters"); such a view did not run and casts no vote;
- *small images*: OSD needs characters of a readable size; an image whose long side is under
  ``TEXT_MIN_SIDE`` is upscaled (bicubic, at most ``TEXT_MAX_UPSCALE`` times) before OSD sees it;
  a large one is reduced to ``TEXT_MAX_SIDE`` (OSD time grows with the page);
- *textures read as script, 180-degree confusions*: OSD runs on all four views of the photo
  (turned 0, 90, 180, 270 degrees clockwise). Each view that ran votes for the turn of the
  *stored* image it implies; the photo is decided only when at least ``TEXT_MIN_AGREE`` views
  ran, every view that ran votes for the same turn, and their mean confidence is at least
  ``TEXT_MIN_CONFIDENCE``. A texture gives scattered or weak votes; a page read upside down in
  one view and right in another gives disagreeing votes: both are rejected;
- *uneven light, faint print*: the view is binarised with a local threshold before OSD (Tesseract's
  own global threshold lost thermal receipts, which OSD then read upside down in every view).

The thresholds were calibrated on real text photos and textures (``benchmarks/orientation.py``,
``$SWEEPCAST_DATA/orientation``): see their docstrings.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal, Sequence

import cv2
import numpy as np

from workers.orientation.geometry import ROTATIONS, rotate_view

RejectReason = Literal["no_cue", "conflicting_rotations", "low_confidence"]

TESSERACT_ENV = "SWEEPCAST_ORIENTATION_TESSERACT"
"""Environment variable naming the tesseract binary (a name on PATH or a path) for the workers."""
TEXT_ENV = "SWEEPCAST_ORIENTATION_TEXT"
"""Environment variable switching the text cue on (1, the default) or off (0) for the workers."""
DEFAULT_TESSERACT = "tesseract"

TEXT_MIN_CONFIDENCE = 2.5
"""Least mean OSD orientation confidence of the agreeing votes. Calibrated on the text/ and noup/ photos at
4 rotations (``benchmarks/orientation.py``): with two agreeing views, the first wrong turn appears at a mean
of 1.5 and every no-up trial is rejected from 0.5 on; 2.0 decided 149/200 text trials, 2.5 (kept, one
step of margin) 134/200, 3.0 116/200, none wrong."""
TEXT_MIN_AGREE = 2
"""Least number of views (of 4) in which OSD ran; every view that ran must vote for the same turn. Long
receipts are read only in their two upright-or-upside-down views (OSD finds too few characters when their
lines run vertically), so 3 rejected many of them (120/200 at a minimum of 1.5 per vote) and gained no
safety on the calibration photos."""
TEXT_MIN_CHARACTERS = 50
"""OSD's ``min_characters_to_try``: a view with fewer character blobs does not run (Tesseract's default)."""
TEXT_MIN_SIDE = 1600
"""Long side (px) a smaller image is upscaled to before OSD (characters of ~10 px become readable)."""
TEXT_MAX_UPSCALE = 3.0
"""Largest upscaling factor (a thumbnail is not made into a page)."""
TEXT_MAX_SIDE = 2400
"""Long side (px) a larger image is reduced to before OSD."""
TEXT_BINARIZE_BLOCK = 31
"""Neighbourhood (px) of the local threshold applied before OSD (odd; about two text lines at 1600 px)."""
TEXT_BINARIZE_C = 15
"""A pixel is ink when it is this much darker than its neighbourhood's Gaussian mean."""
OSD_TIMEOUT_S = 60.0
"""A single OSD call that takes longer is abandoned (the view casts no vote)."""


class TextUnavailable(RuntimeError):
    """Tesseract or its ``osd`` data is not installed (the engine then works on faces alone)."""


@dataclass(frozen=True)
class OsdView:
    """OSD on one view of the photo."""

    view: int
    """Clockwise degrees the stored image was turned to make this view."""
    ran: bool
    """False when OSD did not run (too few characters, an error, a timeout)."""
    rotation: int | None = None
    """Clockwise degrees that make the *stored* image upright, according to this view."""
    confidence: float = 0.0
    """OSD's orientation confidence (0 when it did not run)."""
    script: str | None = None
    script_confidence: float = 0.0
    detail: str | None = None
    """Why OSD did not run."""


@dataclass(frozen=True)
class TextResult:
    """The text cue's decision over the four views."""

    rotation: int | None
    """Clockwise degrees that make the stored image upright; None when rejected."""
    reason: RejectReason | None
    """Why it was rejected: no_cue (OSD ran in too few views: no readable text), conflicting_rotations
    (views voted for different turns), low_confidence (agreeing votes below the threshold)."""
    views: tuple[OsdView, ...]


def text_decision(views: Sequence[OsdView], min_confidence: float = TEXT_MIN_CONFIDENCE,
                  min_agree: int = TEXT_MIN_AGREE) -> tuple[int | None, RejectReason | None]:
    """(turn, None) when at least ``min_agree`` views ran, all voting for one turn, with a mean confidence
    >= ``min_confidence``; else (None, why)."""
    ran = [v for v in views if v.ran and v.rotation is not None]
    if len(ran) < min_agree:
        return None, "no_cue"
    if len({v.rotation for v in ran}) > 1:
        return None, "conflicting_rotations"
    if sum(v.confidence for v in ran) / len(ran) < min_confidence:
        return None, "low_confidence"
    return ran[0].rotation, None


_ROTATE = re.compile(r"^Rotate:\s*(\d+)", re.M)
_CONF = re.compile(r"^Orientation confidence:\s*([-+0-9.eE]+)", re.M)
_SCRIPT = re.compile(r"^Script:\s*(\S+)", re.M)
_SCRIPT_CONF = re.compile(r"^Script confidence:\s*([-+0-9.eE]+)", re.M)


def parse_osd(view: int, stdout: str, stderr: str = "") -> OsdView:
    """An :class:`OsdView` from the text ``tesseract --psm 0`` prints for ``view``.

    Tesseract's ``Rotate`` is the clockwise turn that makes the image it was given upright; the
    stored image needs that turn plus the view's own."""
    rotate, conf = _ROTATE.search(stdout), _CONF.search(stdout)
    if rotate is None or conf is None:
        text = (stderr or stdout).strip().splitlines()
        why = next((line for line in text if "few characters" in line.lower()), None)
        return OsdView(view, False, detail="too few characters" if why else (text[-1][:200] if text else "no output"))
    script, script_conf = _SCRIPT.search(stdout), _SCRIPT_CONF.search(stdout)
    return OsdView(view, True, (view + int(rotate.group(1))) % 360, float(conf.group(1)),
                   script.group(1) if script else None, float(script_conf.group(1)) if script_conf else 0.0)


def prepare(gray: np.ndarray, min_side: int = TEXT_MIN_SIDE, max_side: int = TEXT_MAX_SIDE,
            max_upscale: float = TEXT_MAX_UPSCALE, binarize: bool = True) -> np.ndarray:
    """``gray`` made ready for OSD: small images upscaled (bicubic) towards ``min_side``, large ones reduced
    to ``max_side`` (area) on their long side, then binarised with a local (adaptive Gaussian) threshold.

    Tesseract binarises with one global (Otsu) threshold, which loses faint thermal print and unevenly lit
    photographed pages; on the calibration photos the local threshold turned receipts that OSD read upside
    down in every view into agreeing, confident votes (``TEXT_BINARIZE_BLOCK``)."""
    long_side = max(gray.shape[:2])
    if long_side < min_side:
        s: float | None = min(max_upscale, min_side / long_side)
        interp = cv2.INTER_CUBIC
    elif long_side > max_side:
        s, interp = max_side / long_side, cv2.INTER_AREA
    else:
        s = None
    if s is not None:
        size = (max(1, round(gray.shape[1] * s)), max(1, round(gray.shape[0] * s)))
        gray = cv2.resize(gray, size, interpolation=interp)
    if not binarize:
        return gray
    return cv2.adaptiveThreshold(gray, 255, cv2.ADAPTIVE_THRESH_GAUSSIAN_C, cv2.THRESH_BINARY,
                                 TEXT_BINARIZE_BLOCK, TEXT_BINARIZE_C)


class TesseractOsd:
    """Tesseract's OSD through its command line (one short-lived process per view; thread-safe)."""

    name = "tesseract"

    def __init__(self, binary: str = DEFAULT_TESSERACT, min_confidence: float = TEXT_MIN_CONFIDENCE,
                 min_agree: int = TEXT_MIN_AGREE, min_characters: int = TEXT_MIN_CHARACTERS,
                 timeout_s: float = OSD_TIMEOUT_S) -> None:
        path = shutil.which(binary)
        if path is None:
            raise TextUnavailable(f"the tesseract binary {binary!r} was not found (install the Debian packages "
                                  "tesseract-ocr and tesseract-ocr-osd)")
        self.path = path
        self.version, langs = _probe(path)
        if "osd" not in langs:
            raise TextUnavailable(f"{path} has no 'osd' data (install the Debian package tesseract-ocr-osd)")
        self.min_confidence = min_confidence
        self.min_agree = min_agree
        self.min_characters = min_characters
        self.timeout_s = timeout_s

    def osd(self, view_image: np.ndarray, view: int) -> OsdView:
        """OSD on one view ((H, W) uint8 grey, already prepared)."""
        ok, png = cv2.imencode(".png", view_image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        if not ok:
            return OsdView(view, False, detail="could not encode the view")
        cmd = [self.path, "stdin", "stdout", "--psm", "0", "--dpi", "300",
               "-c", f"min_characters_to_try={self.min_characters}"]
        env = {**os.environ, "OMP_THREAD_LIMIT": "1"}  # one core per call; the callers run in parallel
        try:
            proc = subprocess.run(cmd, input=png.tobytes(), capture_output=True, timeout=self.timeout_s, env=env,
                                  check=False)
        except subprocess.TimeoutExpired:
            return OsdView(view, False, detail=f"OSD took longer than {self.timeout_s:.0f} s")
        except OSError as exc:
            return OsdView(view, False, detail=f"could not run tesseract: {exc}")
        return parse_osd(view, proc.stdout.decode(errors="replace"), proc.stderr.decode(errors="replace"))

    def views(self, gray: np.ndarray) -> tuple[OsdView, ...]:
        """OSD on the four views of ``gray`` ((H, W) uint8, stored orientation, full resolution)."""
        prepared = prepare(gray)
        return tuple(self.osd(rotate_view(prepared, r), r) for r in ROTATIONS)

    def upright(self, gray: np.ndarray) -> TextResult:
        """The turn that shows ``gray``'s text upright, or a rejection with its reason."""
        views = self.views(gray)
        rotation, reason = text_decision(views, self.min_confidence, self.min_agree)
        return TextResult(rotation, reason, views)


def _probe(path: str) -> tuple[str, set[str]]:
    """(version line, installed languages) of the tesseract at ``path``; TextUnavailable when it does not run."""
    try:
        version = subprocess.run([path, "--version"], capture_output=True, timeout=20, check=False)
        langs = subprocess.run([path, "--list-langs"], capture_output=True, timeout=20, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise TextUnavailable(f"cannot run {path}: {exc}") from None
    out = (version.stdout + version.stderr).decode(errors="replace").strip().splitlines()
    if version.returncode != 0 or not out:
        raise TextUnavailable(f"{path} --version failed (exit {version.returncode})")
    listed = (langs.stdout + langs.stderr).decode(errors="replace").splitlines()
    return out[0].strip(), {line.strip() for line in listed if line.strip() and " " not in line.strip()}


@lru_cache(maxsize=8)
def _cached(binary: str) -> TesseractOsd | str:
    try:
        return TesseractOsd(binary)
    except TextUnavailable as exc:
        return str(exc)


def get_text_detector(binary: str = DEFAULT_TESSERACT) -> TesseractOsd | None:
    """The OSD text detector for ``binary`` (probed once per process), or None when it is not installed."""
    found = _cached(binary)
    return found if isinstance(found, TesseractOsd) else None


def text_status(binary: str = DEFAULT_TESSERACT, enabled: bool = True) -> dict[str, object]:
    """What the readiness and engine reports say about the text cue."""
    if not enabled:
        return {"available": False, "enabled": False, "detail": "text cue switched off: faces only"}
    found = _cached(binary)
    if isinstance(found, str):
        return {"available": False, "enabled": True, "detail": f"{found}; faces only"}
    return {"available": True, "enabled": True, "path": found.path, "version": found.version,
            "min_confidence": found.min_confidence, "min_agree": found.min_agree}


def text_settings_from_env() -> tuple[bool, str]:
    """(text cue on, tesseract binary) as the service passes them to its workers."""
    enabled = os.environ.get(TEXT_ENV, "1").strip().lower() not in ("0", "false", "no", "off")
    return enabled, os.environ.get(TESSERACT_ENV) or DEFAULT_TESSERACT
