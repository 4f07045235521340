"""The second cue: which way is up from text, by Tesseract's orientation and script detection (OSD),
verified by reading the text (OCR) the way OSD says is up and upside down; and, when that decides nothing,
by reading the scene's text (sparse OCR) in all four views.

Faces come first (the paper); when they decide nothing, the photo's text may. Tesseract's OSD
(Debian packages ``tesseract-ocr`` and ``tesseract-ocr-osd``) classifies up to a few hundred
character blobs in each of the four orientations and reports the clockwise turn that makes the page
upright, with a confidence. Tesseract's English OCR (``tesseract-ocr-eng``, a dependency of
``tesseract-ocr``) then reads the page turned that way and turned the other way up: real text read
right gives many confident words, read upside down (or a texture read at all) gives few. It is
optional: without the binary or its ``osd`` data the engine works on faces alone and says so
(:func:`text_status`); without ``eng`` data it decides by OSD alone. Tesseract is called through the
``tesserocr`` binding when it is installed (one API object per thread, about twice as fast: no process
and no model load per call), else through its command line.

The rule stays the paper's: a wrong turn is far worse than no answer. The known failure modes,
and what guards each:

- *too few characters*: OSD refuses pages with fewer than ``min_characters_to_try`` blobs
  ("Too few characters"); such a view did not run and casts no vote;
- *small images*: OSD needs characters of a readable size; an image whose long side is under
  ``TEXT_MIN_SIDE`` is upscaled (bicubic, at most ``TEXT_MAX_UPSCALE`` times) before OSD sees it;
  a large one is reduced to ``TEXT_MAX_SIDE`` (OSD time grows with the page);
- *textures read as script*: OSD runs on all four views of the photo (turned 0, 90, 180, 270 degrees
  clockwise); each view that ran votes for the turn of the *stored* image it implies. At least
  ``TEXT_MIN_AGREE`` views must run and every vote must lie on one axis (the candidate turn or its
  opposite): lines of text give that, a texture scatters its votes over both axes and is rejected
  before any OCR. A texture that slips through is not read as words by OCR either;
- *180-degree confusions*: OSD confuses a page with its upside-down self; OCR does not: OCR reads the
  page turned the candidate way and the opposite way, and the turn that reads at least
  ``TEXT_VERIFY_MIN_WORDS`` confident words and ``TEXT_VERIFY_RATIO`` times as many as the other is
  accepted (so a candidate OSD got upside down is turned round by reading); else the candidate on OSD
  alone only when every vote agrees with a mean confidence of at least ``TEXT_MIN_CONFIDENCE`` and
  OCR does not read the other way up clearly better (and, since issue 33, reads real words this way up: pages
  in a script the English OCR cannot read are left to the scene reading with that script's model);
- *uneven light, faint print*: OSD sees the view binarised with a local threshold (Tesseract's own
  global threshold lost thermal receipts, which OSD then read upside down in every view); OCR reads
  the grey page first and, when that does not verify, the binarised one;
- *signs and posters* (a few scattered words: OSD finds too few characters or scatters its votes, the
  block OCR finds no lines; or a script English cannot read): the scene reading
  (:meth:`TesseractOsd.read_scene`) runs Tesseract's sparse-text mode on the whole page in each of the
  four views, in English plus the script model of the script OSD saw most (when installed: Debian
  ``tesseract-ocr-script-hang``, ``-jpan``, ...), and decides the view that reads at least
  ``TEXT_SCENE_MIN_LETTERS`` confident letters and ``TEXT_SCENE_RATIO`` times as many as every other
  view (:func:`scene_turn`). Text read sideways or upside down gives few confident letters; a texture
  gives a few single letters, which do not count;
- *patterns read as letters* (a nadir satellite photo of fields was decided by the scene reading, which counted
  letters): every stage decides only on *real words* (:mod:`workers.orientation.words`: confident, accepted by the
  language's dictionary, horizontal, on lines of one letter size), a minimum of them, read the winning way up and
  not in the same places the other way up. OSD alone (character shapes) no longer decides without them.

The thresholds were calibrated on real text photos and textures (``benchmarks/orientation.py``,
``$SWEEPCAST_DATA/orientation``, with held-out figures by image and by source): see their docstrings.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import threading
from dataclasses import dataclass
from pathlib import Path
from functools import lru_cache
from typing import Iterable, Literal, Sequence

import cv2
import numpy as np

from workers.common.images import encode_png
from workers.orientation.geometry import ROTATIONS, rotate_view
from workers.orientation.words import Evidence, OcrWord, evidence, overlapping, word_lists
from workers.settings import worker_settings

try:  # the optional in-process binding (pip install tesserocr); the command line otherwise
    import tesserocr
except ImportError:  # pragma: no cover - depends on the environment
    tesserocr = None

RejectReason = Literal["no_cue", "conflicting_rotations", "low_confidence"]
Variant = Literal["gray", "binary"]
Backend = Literal["tesserocr", "cli"]

TESSERACT_ENV = "SWEEPCAST_ORIENTATION_TESSERACT"
"""Environment variable naming the tesseract binary (a name on PATH or a path) for the workers."""
DEFAULT_TESSERACT = "tesseract"

TEXT_MIN_CONFIDENCE = 2.5
"""Least mean OSD orientation confidence for a decision by OSD alone (every vote agreeing, OCR not
verifying). Calibrated on the text/ and noup/ photos at 4 rotations (``benchmarks/orientation.py``): the
loosest value with no wrong turn (a scene frame whose four views all voted for one wrong turn sets it), plus
one grid step of margin; the held-out selection agrees (RESULTS.md, orientation_text)."""
TEXT_MIN_AGREE = 2
"""Least number of views (of 4) in which OSD ran. Long receipts are read only in their two
upright-or-upside-down views (OSD finds too few characters when their lines run vertically), so 3
rejected many of them and gained no safety on the calibration photos."""
TEXT_VERIFY_MIN_WORDS = 8
"""Least confident words (:class:`workers.orientation.words.Evidence`) OCR must read on the page turned the candidate way for
an OCR-verified decision. A real page reads many of them upright and few upside down or sideways, a texture
next to none; 8 lies inside the plateau of values that made no wrong turn and decided the most on the benchmark
grid (RESULTS.md, orientation_text)."""
TEXT_VERIFY_RATIO = 3.0
"""The candidate must read this many times as many confident words as the page turned the other way
up (at least 1 counted there). Calibrated like ``TEXT_VERIFY_MIN_WORDS``: verified pages read several times
more words upright, and the ratios around 3 were all safe and decided the same on the photos."""
TEXT_VERIFY_MIN_REAL = 3
"""... and at least this many real words (:func:`workers.orientation.words.real_words`: in the dictionary, along
lines of one size), ``TEXT_VERIFY_RATIO`` times as many as the page turned the other way reads in the same places.
Chosen on the tuning split of the text photos (``benchmarks/orientation.py``, section orientation_text)."""
TEXT_OSD_MIN_REAL = 2
"""OSD alone decides only when OCR reads at least this many real words the candidate way up and fewer the other way
up: OSD's votes are character shapes, not text, and lines or stripes in a texture can agree on one axis."""
TEXT_MIN_CHARACTERS = 50
"""OSD's ``min_characters_to_try``: a view with fewer character blobs does not run (Tesseract's default)."""
TEXT_MIN_SIDE = 1600
"""Long side (px) a smaller image is upscaled to before OSD and OCR (characters of ~10 px become readable)."""
TEXT_MAX_UPSCALE = 3.0
"""Largest upscaling factor (a thumbnail is not made into a page)."""
TEXT_MAX_SIDE = 2400
"""Long side (px) a larger image is reduced to before OSD."""
TEXT_OCR_MAX_SIDE = 1600
"""Long side (px) of the page OCR reads (OCR time grows with the page; receipts still read enough words)."""
TEXT_OCR_WINDOW = 800
"""Side (px) of the square OCR reads, placed where the page has the most ink: reading a dense page whole takes
seconds, and a window still holds many lines of a receipt at ``TEXT_OCR_MAX_SIDE``."""
TEXT_BINARIZE_BLOCK = 31
"""Neighbourhood (px) of the local threshold applied before OSD (odd; about two text lines at 1600 px)."""
TEXT_BINARIZE_C = 15
"""A pixel is ink when it is this much darker than its neighbourhood's Gaussian mean."""
OSD_TIMEOUT_S = 60.0
"""A single OSD or OCR call through the command line that takes longer is abandoned (no vote, no words)."""
OCR_VARIANTS: tuple[Variant, ...] = ("gray", "binary")
"""The pages OCR reads, in order, until one verifies: the grey page (posters, photos: white-on-colour text
that a local threshold breaks), then the binarised one (faint thermal receipts)."""
TEXT_SCENE_MIN_WORDS = 2
"""Least real words (:func:`workers.orientation.words.real_words`) the scene reading (:meth:`TesseractOsd.read_scene`)
must find in its best view to decide: words, not letters. Before, 8 confident *letters* decided, and a nadir
satellite photo of fields read as letters in one view was decided."""
TEXT_SCENE_MIN_LETTERS = 8
"""... holding at least this many letters between them (about two words, what a road sign holds)."""
TEXT_SCENE_RATIO = 3.0
"""... and this many times the real letters of the best of the other three views (at least 1 counted there), with
the opposite view reading at most 1/ratio as many real words in the same places: text read upright reads as
nonsense upside down (the same ratio as the verifying OCR's ``TEXT_VERIFY_RATIO``)."""
TEXT_SCENE_PSM = 11
"""Tesseract's page segmentation for the scene reading: sparse text (find as much text as possible in no particular
order): signs and posters are scattered lines that the block mode of the verifying OCR does not find."""
LATIN_SCRIPTS = frozenset({"Latin", "Common"})
"""OSD scripts the English model reads already: no script model added for them."""
SCRIPT_MODELS = {"Han": "HanS"}
"""Tesseract's script models are named after the scripts OSD reports (``Hangul``, ``Japanese``, ``Thai``,
``Cyrillic``, ...; Debian ``tesseract-ocr-script-*``), except Han, read by the simplified-Chinese model."""

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
class WordCount:
    """OCR of the page turned one way (:meth:`TesseractOsd.verify`): what it read, summed up."""

    variant: Variant
    """Which page was read: the grey one or the binarised one."""
    rotation: int
    """Clockwise degrees the stored image was turned before reading (the turn this reading tests)."""
    evidence: Evidence = Evidence()

    @property
    def words(self) -> int:
        """Confident, letter-made words read."""
        return self.evidence.words


@dataclass(frozen=True)
class LetterCount:
    """The scene reading of the page turned one way (:meth:`TesseractOsd.read_scene`), summed up."""

    rotation: int
    """Clockwise degrees the stored image was turned before reading."""
    evidence: Evidence = Evidence()

    @property
    def letters(self) -> int:
        """Letters of the confident words read (real words or not)."""
        return self.evidence.letters


@dataclass(frozen=True)
class TextResult:
    """The text cue's decision."""

    rotation: int | None
    """Clockwise degrees that make the stored image upright; None when rejected."""
    reason: RejectReason | None
    """Why it was rejected: no_cue (OSD ran in too few views: no readable text), conflicting_rotations
    (views voted for both axes or for opposite turns not settled by OCR, or OCR reads the page better the
    other way up), low_confidence (neither OCR nor OSD clear enough)."""
    views: tuple[OsdView, ...]
    words: tuple[WordCount, ...] = ()
    """OCR readings of the candidate turn and its opposite (empty when OCR did not run)."""
    how: Literal["ocr", "osd", "scene"] | None = None
    """What decided: OCR verified the candidate, OSD alone (every vote agreeing, confident), or the scene reading
    (sparse OCR of all four views, when neither of the others decided)."""
    scene: tuple[LetterCount, ...] = ()
    """The scene reading's letters per view (empty when it did not run)."""
    scene_language: str | None = None
    """The Tesseract languages of the scene reading (``eng``, or a script model and ``eng``)."""

    def summary(self) -> str:
        """A few words for people on how the text decided."""
        agreeing = sum(v.ran and v.rotation == self.rotation for v in self.views)
        osd = f"OSD in {agreeing} of {len(self.views)} views"
        if self.how == "scene":
            best = next((c.evidence for c in self.scene if c.rotation == self.rotation), Evidence())
            other = max((c.evidence.real for c in self.scene if c.rotation != self.rotation), default=0)
            return (f"scene text read ({self.scene_language}): {best.real} dictionary words ({best.real_letters} "
                    f"letters) this way up, at most {other} turned any other way")
        c, o = _best_pair(self.words, self.rotation)
        if self.how != "ocr":
            return f"{osd} (OSD, with {c.real} dictionary words read this way up and {o.real} the other way up)"
        return (f"{osd}, confirmed by OCR ({c.words} confident words, {c.real} in the dictionary, read this way up; "
                f"{o.words} the other way up)")


def scene_turn(counts: Sequence[LetterCount], min_words: int = TEXT_SCENE_MIN_WORDS,
               min_letters: int = TEXT_SCENE_MIN_LETTERS, ratio: float = TEXT_SCENE_RATIO) -> int | None:
    """The view the scene reading decides: the one with the most real letters when it holds at least ``min_words``
    real words with ``min_letters`` letters, ``ratio`` times the real letters of every other view (at least 1
    counted there), and the opposite view reads at most 1/``ratio`` as many real words in the same places; None
    otherwise (or when not every one of the four views was read)."""
    if sorted(c.rotation for c in counts) != list(ROTATIONS):
        return None
    by_view = {c.rotation: c.evidence for c in counts}
    best_view = max(ROTATIONS, key=lambda r: (by_view[r].real_letters, by_view[r].real))
    best = by_view[best_view]
    other = max(e.real_letters for r, e in by_view.items() if r != best_view)
    same_places = overlapping(by_view[(best_view + 180) % 360].regions, best.regions)
    if (best.real >= min_words and best.real_letters >= min_letters and best.real_letters >= ratio * max(other, 1)
            and same_places * ratio <= best.real):
        return best_view
    return None


def scene_language(views: Sequence[OsdView], installed: Iterable[str]) -> str:
    """The languages of the scene reading: English, plus the script model of the script OSD saw most (summed
    script confidence over the views that ran) when it is not Latin and its model is installed
    (``SCRIPT_MODELS``)."""
    totals: dict[str, float] = {}
    for v in views:
        if v.ran and v.script:
            totals[v.script] = totals.get(v.script, 0.0) + v.script_confidence
    if not totals:
        return "eng"
    script = max(sorted(totals), key=lambda k: totals[k])
    model = SCRIPT_MODELS.get(script, script)
    return f"{model}+eng" if script not in LATIN_SCRIPTS and model in set(installed) else "eng"


def decide_text(views: Sequence[OsdView], words: Sequence[WordCount] = (), scene: Sequence[LetterCount] = (),
                min_confidence: float = TEXT_MIN_CONFIDENCE, min_agree: int = TEXT_MIN_AGREE,
                min_words: int = TEXT_VERIFY_MIN_WORDS, ratio: float = TEXT_VERIFY_RATIO,
                scene_letters: int = TEXT_SCENE_MIN_LETTERS, scene_ratio: float = TEXT_SCENE_RATIO,
                min_real: int = TEXT_VERIFY_MIN_REAL, scene_words: int = TEXT_SCENE_MIN_WORDS,
                osd_real: int = TEXT_OSD_MIN_REAL,
                ) -> tuple[int | None, RejectReason | None, Literal["ocr", "osd", "scene"] | None]:
    """The text cue's whole rule: OSD proposes and OCR verifies (:func:`osd_candidate`, :func:`text_decision`);
    when that decides nothing, the scene reading of the four views (:func:`scene_turn`). A rejection keeps the
    first stage's reason, except that a scene read clearly in some view is not "no_cue" but "low_confidence"."""
    candidate, why = osd_candidate(views, min_agree)
    if candidate is not None:
        rotation, why, how = text_decision(views, words, min_confidence, min_agree, min_words, ratio, min_real,
                                           osd_real)
        if rotation is not None:
            return rotation, None, how
    turn = scene_turn(scene, scene_words, scene_letters, scene_ratio)
    if turn is not None:
        return turn, None, "scene"
    if why == "no_cue" and any(c.evidence.real_letters >= scene_letters for c in scene):
        why = "low_confidence"
    return None, why, None


def osd_candidate(views: Sequence[OsdView], min_agree: int = TEXT_MIN_AGREE) -> tuple[int | None, RejectReason | None]:
    """(the candidate turn, None) from the OSD votes, or (None, why): no_cue when fewer than ``min_agree``
    views ran, conflicting_rotations when the votes lie on both axes (a texture; lines of text give votes
    for one turn or its opposite). The candidate is the turn with the largest summed confidence."""
    ran = [v for v in views if v.ran and v.rotation is not None]
    if len(ran) < min_agree:
        return None, "no_cue"
    totals: dict[int, float] = {}
    for v in ran:
        totals[v.rotation] = totals.get(v.rotation, 0.0) + v.confidence
    candidate = max(sorted(totals), key=lambda r: totals[r])
    if any(v.rotation not in (candidate, (candidate + 180) % 360) for v in ran):
        return None, "conflicting_rotations"
    return candidate, None


def _pair(words: Sequence[WordCount], rotation: int | None, variant: Variant) -> tuple[Evidence, Evidence] | None:
    """(the reading at ``rotation``, at its opposite) of ``variant``, or None when it was not read both ways."""
    if rotation is None:
        return None
    got = {w.rotation: w.evidence for w in words if w.variant == variant}
    opposite = (rotation + 180) % 360
    return (got[rotation], got[opposite]) if rotation in got and opposite in got else None


def _best_pair(words: Sequence[WordCount], rotation: int | None) -> tuple[Evidence, Evidence]:
    """The variant's pair with the most real words read at ``rotation`` (empty evidence when none was read)."""
    pairs = [p for var in OCR_VARIANTS if (p := _pair(words, rotation, var)) is not None]
    return max(pairs, key=lambda p: (p[0].real, p[0].words), default=(Evidence(), Evidence()))


def ocr_verdict(candidate: int, words: Sequence[WordCount], variant: Variant, min_words: int = TEXT_VERIFY_MIN_WORDS,
                ratio: float = TEXT_VERIFY_RATIO, min_real: int = TEXT_VERIFY_MIN_REAL
                ) -> Literal["for", "against", "unclear"]:
    """What the OCR of ``variant`` says about ``candidate``: for (at least ``min_words`` confident words and
    ``min_real`` real ones, each ``ratio`` times what the other way up reads: the real words counted in the same
    places), against (the other way up reads at least ``min_words`` and more words than the candidate), else unclear."""
    pair = _pair(words, candidate, variant)
    if pair is None:
        return "unclear"
    c, o = pair
    same_places = overlapping(o.regions, c.regions)
    if (c.words >= min_words and c.words >= ratio * max(o.words, 1) and c.real >= min_real
            and c.real >= ratio * max(same_places, 1)):
        return "for"
    if o.words >= min_words and o.words > c.words:
        return "against"
    return "unclear"


def ocr_turn(candidate: int, words: Sequence[WordCount], variant: Variant, min_words: int = TEXT_VERIFY_MIN_WORDS,
             ratio: float = TEXT_VERIFY_RATIO, min_real: int = TEXT_VERIFY_MIN_REAL) -> int | None:
    """The turn on the candidate's axis that the OCR of ``variant`` verifies: the candidate or its opposite
    (OSD's 180-degree confusion, settled by reading), or None when neither reads clearly better."""
    opposite = (candidate + 180) % 360
    if ocr_verdict(candidate, words, variant, min_words, ratio, min_real) == "for":
        return candidate
    if ocr_verdict(opposite, words, variant, min_words, ratio, min_real) == "for":
        return opposite
    return None


def text_decision(views: Sequence[OsdView], words: Sequence[WordCount] = (),
                  min_confidence: float = TEXT_MIN_CONFIDENCE, min_agree: int = TEXT_MIN_AGREE,
                  min_words: int = TEXT_VERIFY_MIN_WORDS, ratio: float = TEXT_VERIFY_RATIO,
                  min_real: int = TEXT_VERIFY_MIN_REAL, osd_real: int = TEXT_OSD_MIN_REAL,
                  ) -> tuple[int | None, RejectReason | None, Literal["ocr", "osd"] | None]:
    """(turn, None, how) or (None, why, None) for the OSD ``views`` and the OCR ``words`` of the candidate.

    The first OCR variant (``OCR_VARIANTS`` order; a variant not read is skipped) that verifies a turn on the
    candidate's axis (:func:`ocr_turn`: the candidate, or its opposite when OSD confused the page with its
    upside-down self) decides it. Otherwise OSD decides when every vote agrees with a mean confidence of at least
    ``min_confidence``, no OCR variant says "against" the candidate, and OCR read at least ``osd_real`` real words
    the candidate way up and fewer the other way up (OSD classifies shapes; the words say they are text)."""
    candidate, why = osd_candidate(views, min_agree)
    if candidate is None:
        return None, why, None
    read = [var for var in OCR_VARIANTS if any(w.variant == var for w in words)]
    for var in read:
        turn = ocr_turn(candidate, words, var, min_words, ratio, min_real)
        if turn is not None:
            return turn, None, "ocr"
    ran = [v for v in views if v.ran and v.rotation is not None]
    if any(ocr_verdict(candidate, words, var, min_words, ratio, min_real) == "against" for var in read) or any(
            v.rotation != candidate for v in ran):
        return None, "conflicting_rotations", None
    if sum(v.confidence for v in ran) / len(ran) < min_confidence:
        return None, "low_confidence", None
    c, o = _best_pair(words, candidate)
    if c.real < osd_real or o.real >= c.real:
        return None, "low_confidence", None
    return candidate, None, "osd"


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


def parse_tsv_words(tsv: str) -> list[OcrWord]:
    """The words (level 5 rows) of Tesseract's ``tsv`` output, with their boxes; the command line cannot say whether
    the dictionary accepts a word (``dictionary`` None)."""
    out = []
    for line in tsv.splitlines()[1:]:
        cols = line.split("\t")
        if len(cols) >= 12 and cols[0] == "5" and cols[11].strip():
            try:
                box = tuple(float(v) for v in cols[6:10])
                out.append(OcrWord(cols[11].strip(), float(cols[10]), box))
            except ValueError:
                continue
    return out


def _resize_long_side(gray: np.ndarray, min_side: int, max_side: int, max_upscale: float) -> np.ndarray:
    long_side = max(gray.shape[:2])
    if long_side < min_side:
        s, interp = min(max_upscale, min_side / long_side), cv2.INTER_CUBIC
    elif long_side > max_side:
        s, interp = max_side / long_side, cv2.INTER_AREA
    else:
        return gray
    size = (max(1, round(gray.shape[1] * s)), max(1, round(gray.shape[0] * s)))
    return cv2.resize(gray, size, interpolation=interp)


def binarize_page(gray: np.ndarray) -> np.ndarray:
    """A local (adaptive Gaussian) threshold: ink is ``TEXT_BINARIZE_C`` darker than its neighbourhood."""
    return cv2.adaptiveThreshold(gray, 255, cv2.ADAPTIVE_THRESH_GAUSSIAN_C, cv2.THRESH_BINARY,
                                 TEXT_BINARIZE_BLOCK, TEXT_BINARIZE_C)


def prepare(gray: np.ndarray, min_side: int = TEXT_MIN_SIDE, max_side: int = TEXT_MAX_SIDE,
            max_upscale: float = TEXT_MAX_UPSCALE, binarize: bool = True) -> np.ndarray:
    """``gray`` made ready for OSD: small images upscaled (bicubic) towards ``min_side``, large ones reduced
    to ``max_side`` (area) on their long side, then binarised with a local (adaptive Gaussian) threshold.

    Tesseract binarises with one global (Otsu) threshold, which loses faint thermal print and unevenly lit
    photographed pages; on the calibration photos the local threshold turned receipts that OSD read upside
    down in every view into agreeing, confident votes (``TEXT_BINARIZE_BLOCK``)."""
    gray = _resize_long_side(gray, min_side, max_side, max_upscale)
    return binarize_page(gray) if binarize else gray


def ocr_pages(gray: np.ndarray, window: int | None = None) -> dict[Variant, np.ndarray]:
    """The pages OCR reads (``OCR_VARIANTS``): ``gray`` sized like for OSD but at most ``TEXT_OCR_MAX_SIDE``
    long, cut to the ``TEXT_OCR_WINDOW`` square with the most ink (the local threshold's dark pixels, searched
    on a grid), and that window binarised."""
    window = TEXT_OCR_WINDOW if window is None else window
    page = _resize_long_side(gray, TEXT_MIN_SIDE, TEXT_OCR_MAX_SIDE, TEXT_MAX_UPSCALE)
    binary = binarize_page(page)
    h, w = page.shape
    wh, ww = min(h, window), min(w, window)
    if (wh, ww) != (h, w):
        ink = cv2.integral((binary < 128).astype(np.uint8))
        step = max(16, window // 8)
        best, y0, x0 = -1, 0, 0
        for y in sorted({*range(0, h - wh + 1, step), h - wh}):
            for x in sorted({*range(0, w - ww + 1, step), w - ww}):
                n = int(ink[y + wh, x + ww] - ink[y, x + ww] - ink[y + wh, x] + ink[y, x])
                if n > best:
                    best, y0, x0 = n, y, x
        page, binary = page[y0:y0 + wh, x0:x0 + ww], binary[y0:y0 + wh, x0:x0 + ww]
    return {"gray": np.ascontiguousarray(page), "binary": np.ascontiguousarray(binary)}


class TesseractOsd:
    """Tesseract's OSD and OCR, through ``tesserocr`` (one API object per thread) when it is installed and
    ``use_api`` allows, else through the command line (one short-lived process per call). Thread-safe."""

    name = "tesseract"

    def __init__(self, binary: str = DEFAULT_TESSERACT, min_confidence: float = TEXT_MIN_CONFIDENCE,
                 min_agree: int = TEXT_MIN_AGREE, min_characters: int = TEXT_MIN_CHARACTERS,
                 timeout_s: float = OSD_TIMEOUT_S, use_api: bool | None = None, exhaustive: bool = False,
                 wordlists: Path | str | None = None) -> None:
        path = shutil.which(binary)
        if path is None:
            raise TextUnavailable(f"the tesseract binary {binary!r} was not found (install the Debian packages "
                                  "tesseract-ocr and tesseract-ocr-osd)")
        self.path = path
        self.version, langs, self.tessdata = _probe(path)
        if "osd" not in langs:
            raise TextUnavailable(f"{path} has no 'osd' data (install the Debian package tesseract-ocr-osd)")
        self.ocr = "eng" in langs
        """Whether OCR verification and the scene reading are available (the ``eng`` data); without it OSD decides
        alone."""
        self.script_models = tuple(sorted(lang for lang in langs if lang[:1].isupper()))
        """The installed script models (``Hangul``, ``Japanese``, ...) the scene reading can add to English."""
        self.wordlists = worker_settings().orientation_wordlists if wordlists is None else Path(wordlists)
        self.vocabulary = word_lists(self.wordlists)
        """The words the word lists know (lower case; :func:`workers.orientation.words.real_words`)."""
        self.min_confidence = min_confidence
        self.min_agree = min_agree
        self.min_characters = min_characters
        self.timeout_s = timeout_s
        self.exhaustive = exhaustive
        """Read every OCR variant even after one verified (benchmarks: the calibration needs them all; the
        decision is the same)."""
        self.exhaustive_scene = exhaustive
        """Run the scene reading even when the first stage decided (the decision is the same)."""
        want_api = (use_api is None or use_api) and tesserocr is not None and self.tessdata is not None
        if use_api and not want_api:
            raise TextUnavailable("the tesserocr binding is not installed (pip install tesserocr)")
        self.backend: Backend = "tesserocr" if want_api else "cli"
        self._local = threading.local()

    # ---- the two backends --------------------------------------------------------------------------------------

    def _api(self, lang: str, psm: int | None = None):
        apis = self._local.__dict__.setdefault("apis", {})
        key = (lang, psm)
        if key not in apis:
            if lang == "osd":
                api = tesserocr.PyTessBaseAPI(path=self.tessdata, lang="osd", psm=tesserocr.PSM.OSD_ONLY)
                api.SetVariable("min_characters_to_try", str(self.min_characters))
            else:
                api = tesserocr.PyTessBaseAPI(path=self.tessdata, lang=lang,
                                              psm=tesserocr.PSM.SINGLE_BLOCK if psm is None else psm)
            apis[key] = api
        return apis[key]

    def _run(self, image: np.ndarray, args: list[str]) -> tuple[str, str] | str:
        """(stdout, stderr) of the tesseract command line on ``image``, or why it did not run."""
        try:
            png = encode_png(image, level=1)
        except ValueError:
            return "could not encode the view"
        env = {**os.environ, "OMP_THREAD_LIMIT": "1"}  # one core per call; the callers run in parallel
        try:
            proc = subprocess.run([self.path, "stdin", "stdout", "--dpi", "300", *args], input=png,
                                  capture_output=True, timeout=self.timeout_s, env=env, check=False)
        except subprocess.TimeoutExpired:
            return f"tesseract took longer than {self.timeout_s:.0f} s"
        except OSError as exc:
            return f"could not run tesseract: {exc}"
        return proc.stdout.decode(errors="replace"), proc.stderr.decode(errors="replace")

    def osd(self, view_image: np.ndarray, view: int) -> OsdView:
        """OSD on one view ((H, W) uint8 grey, already prepared)."""
        if self.backend == "tesserocr":
            from PIL import Image

            api = self._api("osd")
            api.SetImage(Image.fromarray(view_image))
            api.SetSourceResolution(300)
            found = api.DetectOrientationScript()
            if not found:
                return OsdView(view, False, detail="too few characters")
            # orient_deg is the page's counter-clockwise orientation: the clockwise turn undoing it
            rotate = (360 - int(found["orient_deg"])) % 360
            return OsdView(view, True, (view + rotate) % 360, float(found["orient_conf"]), found.get("script_name"),
                           float(found.get("script_conf") or 0.0))
        out = self._run(view_image, ["--psm", "0", "-c", f"min_characters_to_try={self.min_characters}"])
        if isinstance(out, str):
            return OsdView(view, False, detail=out)
        return parse_osd(view, *out)

    def words(self, page: np.ndarray, lang: str = "eng", psm: int = 6) -> list[OcrWord]:
        """Every word OCR in ``lang`` reads on ``page`` ((H, W) uint8) with Tesseract's page segmentation ``psm``
        (6: one block, the verifying OCR; 11: sparse text, the scene reading): text, confidence 0-100, box in
        ``page`` px, and whether the language's dictionary accepts it (tesserocr only)."""
        if self.backend == "tesserocr":
            from PIL import Image

            api = self._api(lang, None if psm == 6 else psm)
            api.SetImage(Image.fromarray(page))
            api.SetSourceResolution(300)
            api.Recognize()
            level, out = tesserocr.RIL.WORD, []
            iterator = api.GetIterator()
            if iterator is None:
                return out
            for word in tesserocr.iterate_level(iterator, level):
                try:
                    text = word.GetUTF8Text(level)
                    x0, y0, x1, y1 = word.BoundingBox(level)
                    out.append(OcrWord(text, float(word.Confidence(level)), (float(x0), float(y0), float(x1 - x0),
                                                                             float(y1 - y0)),
                                       bool(word.WordIsFromDictionary())))
                except RuntimeError:  # an empty word
                    continue
            return out
        got = self._run(page, ["--psm", str(psm), "-l", lang, "tsv"])
        return [] if isinstance(got, str) else parse_tsv_words(got[0])

    # ---- the cue ----------------------------------------------------------------------------------------------

    def views(self, gray: np.ndarray) -> tuple[OsdView, ...]:
        """OSD on the four views of ``gray`` ((H, W) uint8, stored orientation, full resolution)."""
        prepared = prepare(gray)
        return tuple(self.osd(rotate_view(prepared, r), r) for r in ROTATIONS)

    def verify(self, gray: np.ndarray, candidate: int) -> tuple[WordCount, ...]:
        """OCR of ``gray`` turned ``candidate`` and the opposite way, page variant by variant (``OCR_VARIANTS``)
        until one verifies either turn (all of them when ``exhaustive``)."""
        if not self.ocr:
            return ()
        out: list[WordCount] = []
        for variant, page in ocr_pages(gray).items():
            height, width = page.shape[:2]
            for r in (candidate, (candidate + 180) % 360):
                out.append(WordCount(variant, r, evidence(self.words(rotate_view(page, r)), r, width, height,
                                                          self.vocabulary)))
            if not self.exhaustive and ocr_turn(candidate, out, variant) is not None:
                break
        return tuple(out)

    def read_scene(self, gray: np.ndarray, lang: str = "eng") -> tuple[LetterCount, ...]:
        """The scene reading: sparse-text OCR (``TEXT_SCENE_PSM``) in ``lang`` of ``gray`` ((H, W) uint8, stored
        orientation) sized like the verifying OCR's page (whole, no window), in each of the four views."""
        page = _resize_long_side(gray, TEXT_MIN_SIDE, TEXT_OCR_MAX_SIDE, TEXT_MAX_UPSCALE)
        height, width = page.shape[:2]
        return tuple(LetterCount(r, evidence(self.words(rotate_view(page, r), lang, TEXT_SCENE_PSM), r, width, height,
                                             self.vocabulary)) for r in ROTATIONS)

    def upright(self, gray: np.ndarray) -> TextResult:
        """The turn that shows ``gray``'s text upright, or a rejection with its reason: OSD proposes, OCR verifies;
        when that decides nothing, the scene reading of the four views (:func:`decide_text`)."""
        views = self.views(gray)
        candidate, _ = osd_candidate(views, self.min_agree)
        words = self.verify(gray, candidate) if candidate is not None else ()
        rotation, reason, how = decide_text(views, words, (), self.min_confidence, self.min_agree)
        if not self.ocr or (rotation is not None and not self.exhaustive_scene):
            return TextResult(rotation, reason, views, words, how)
        lang = scene_language(views, self.script_models)
        scene = self.read_scene(gray, lang)
        rotation, reason, how = decide_text(views, words, scene, self.min_confidence, self.min_agree)
        return TextResult(rotation, reason, views, words, how, scene, lang)


_TESSDATA = re.compile(r'List of available languages in "([^"]+)"')


def _probe(path: str) -> tuple[str, set[str], str | None]:
    """(version line, installed languages, tessdata folder) of the tesseract at ``path``; TextUnavailable when
    it does not run."""
    try:
        version = subprocess.run([path, "--version"], capture_output=True, timeout=20, check=False)
        langs = subprocess.run([path, "--list-langs"], capture_output=True, timeout=20, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise TextUnavailable(f"cannot run {path}: {exc}") from None
    out = (version.stdout + version.stderr).decode(errors="replace").strip().splitlines()
    if version.returncode != 0 or not out:
        raise TextUnavailable(f"{path} --version failed (exit {version.returncode})")
    text = (langs.stdout + langs.stderr).decode(errors="replace")
    folder = _TESSDATA.search(text)
    tessdata = folder.group(1) if folder and os.path.isdir(folder.group(1)) else None
    listed = text.splitlines()
    return out[0].strip(), {line.strip() for line in listed if line.strip() and " " not in line.strip()}, tessdata


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
            "backend": found.backend, "ocr_verification": found.ocr, "scene_reading": found.ocr,
            "script_models": list(found.script_models),
            "wordlists": str(found.wordlists), "wordlist_words": len(found.vocabulary),
            "min_confidence": found.min_confidence, "min_agree": found.min_agree}


def text_settings_from_env() -> tuple[bool, str]:
    """(text cue on, tesseract binary) as the service passes them to its workers."""
    settings = worker_settings()
    return settings.orientation_text, settings.orientation_tesseract or DEFAULT_TESSERACT
