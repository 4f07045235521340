"""The second cue: which way is up from the photo's text, when the faces decide nothing.

Cheap evidence first (DESIGN.md). Most photos of a library hold neither a face nor text, so the cue starts with a
gate that costs tens of milliseconds: a text-detection network finds the photo's text lines on a small copy
(:mod:`workers.orientation.textlines`). No line: no text, and nothing more is done. Lines: their axis leaves two
turns, and the line strips are read both ways up (:mod:`workers.orientation.linereader`), by the cheapest reader first
(Tesseract's English on a page of strips), then PaddleOCR's recogniser (photographed and styled text), then a
Tesseract script model (the script its OSD sees on the strips), stopping at the first reading that decides. Only
the strips are read, at the resolution their letters need (the photo is decoded again, larger, only then).

The rule stays the paper's: a wrong turn is far worse than no answer. A reading decides only on *real words*
(:func:`workers.orientation.words.real_words`: confident, known to a dictionary, horizontal, one letter size)
on several lines, many times more than the same strips read the other way up (:func:`workers.orientation.linereader.
decide_pair`); textures, fields seen from above and patterns may make the gate find "lines", but they do not read
as dictionary words. The previous releases' cue (Tesseract OSD on four views of the page, OCR of a window, sparse
OCR of the whole page in four views) cost seconds per photo: ``benchmarks/RESULTS.md`` (orientation_text) compares
the two on the same photos.
"""
from __future__ import annotations

import statistics
import threading
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import Literal

import numpy as np

from workers.orientation.linereader import (EARLY_LINES, RECOGNIZER_LINES, STRIP_HEIGHT, TESSERACT_LINES,
                                            PairVerdict, Reader, RecognizerLines, TesseractLines, cut_strip,
                                            decided_early, joined, strip_page)
from workers.orientation.textdata import Tessdata, find_tessdata, find_vocabulary
from workers.orientation.geometry import rotate_view
from workers.orientation.textlines import LineScan, LoadImage, TextLine, get_line_detector, upscaler
from workers.orientation.words import Lexicon
from workers.settings import worker_settings

RejectReason = Literal["no_cue", "conflicting_rotations", "low_confidence"]

READ_MIN_LINE_PX = 24.0
"""Least height (px) a line should have in the image its strips are cut from: smaller lines are read from a larger
decode of the photo (letters of 24 px and more read well; Tesseract's strips are 32 px, the recogniser's 48)."""
SCRIPT_MODELS = {"Han": "HanS"}
"""Tesseract's script models are named after the scripts its OSD reports (``Hangul``, ``Japanese``, ``Thai``,
``Arabic``, ...), except Han, read by the simplified-Chinese model."""
LATIN_SCRIPTS = frozenset({"Latin", "Common"})
"""Scripts the English readers read already: no script model for them."""


@dataclass(frozen=True)
class TextResult:
    """The text cue's decision, and what it read."""

    rotation: int | None
    """Clockwise degrees that make the stored image upright; None when rejected."""
    reason: RejectReason | None
    """Why it was rejected: no_cue (no text lines, or none read as words any way up), low_confidence (words read,
    but not clearly more one way up than the other)."""
    lines: int = 0
    """Text lines the gate found."""
    zoomed: bool = False
    """Whether the gate looked again, closer (small print)."""
    readings: tuple[PairVerdict, ...] = ()
    """Each reading of the strips, both ways up, in the order they ran."""
    how: Reader | None = None
    """The reader whose reading decided."""
    script: str | None = None
    """The script Tesseract's OSD saw on the strips, when the script reader ran."""

    def summary(self) -> str:
        """A few words for people on how the text decided."""
        verdict = next((v for v in self.readings if v.turn is not None and v.turn == self.rotation), None)
        if verdict is None:
            return f"{self.lines} text lines found, not read clearly either way up"
        this, other = (verdict.first, verdict.second) if verdict.first.turn == self.rotation else (verdict.second,
                                                                                                    verdict.first)
        who = {"tesseract": "Tesseract", "recognizer": "the PP-OCR recogniser",
               "script": f"Tesseract's {self.script} model"}[this.reader]
        return (f"{self.lines} text lines found; {who} read {this.real} dictionary words on {this.lines} lines this way "
                f"up, {other.real} the other way up")


class TextCue:
    """The gate, then the line readers (module docstring). Thread-safe; built once per process
    (:func:`get_text_cue`)."""

    def __init__(self, tessdata: Tessdata | None, vocabulary: Lexicon, vocabulary_source: str,
                 recognizer: bool = True) -> None:
        self.detector = get_line_detector()
        self.tessdata = tessdata
        self.tesseract = _tesseract(tessdata)
        self.recognizer = RecognizerLines() if recognizer else None
        self.vocabulary = vocabulary
        self.vocabulary_source = vocabulary_source

    def upright(self, gray: np.ndarray, load: LoadImage | None = None) -> TextResult:
        """The turn that shows ``gray``'s text upright, or a rejection with its reason. ``gray`` ((H, W) uint8, stored
        orientation) is what the gate looks at; ``load`` gives a larger decode of the same photo for lines too small
        to read in ``gray`` (default: ``gray`` upscaled)."""
        load = load or upscaler(gray)
        scan = self.detector.scan(gray, load)
        if not scan.lines:
            return TextResult(None, "no_cue", 0, scan.zoomed)
        readings: list[PairVerdict] = []
        found = self._read_scan(gray, scan, load, readings)
        if found is None and QUARTER_TURN_PASS:  # lines, none read clearly: look again turned a quarter
            turned = rotate_view(gray, 90)
            again = self.detector.scan(turned, _turned_load(load))
            if again.lines:
                found = self._read_scan(turned, again, _turned_load(load), readings, quarter=90)
        zoomed = scan.zoomed
        if found is not None:
            verdict, script = found
            return TextResult(verdict.turn, None, len(scan.lines), zoomed, tuple(readings), verdict.first.reader,
                              script)
        read_any = any(v.first.real or v.second.real or v.first.confident or v.second.confident for v in readings)
        return TextResult(None, "low_confidence" if read_any else "no_cue", len(scan.lines), zoomed,
                          tuple(readings), None, None)

    def _read_scan(self, gray: np.ndarray, scan: LineScan, load: LoadImage, readings: list[PairVerdict],
                   quarter: int = 0) -> tuple[PairVerdict, str | None] | None:
        """Read ``scan``'s lines of ``gray`` axis by axis, reader by reader, until a reading decides: (the deciding
        verdict, the script seen), or None. ``quarter``: ``gray`` is the stored image turned that many degrees
        clockwise; turns are given for the stored image."""
        script = None
        for axis in scan.axes():
            lines = scan.on_axis(axis)[:max(sum(TESSERACT_LINES), RECOGNIZER_LINES)]
            image, lines = _lines_image(gray, lines, load)
            for verdict, seen in self._readings(image, lines):
                verdict = _turned_by(verdict, quarter)
                readings.append(verdict)
                script = seen or script
                if verdict.turn is not None:
                    return verdict, script
        return None

    def _readings(self, image: np.ndarray, lines: list[TextLine]):
        """Each reader's reading of ``lines`` (one axis, px of ``image``), cheapest first, as (verdict, script seen):
        Tesseract's English on the first lines (their first half alone where it decides by a wide margin,
        ``EARLY_LINES``), then on more; PaddleOCR's recogniser; a Tesseract script model for the
        script its OSD sees on the lines. Where English reads no word it knows on the first lines either way up, the
        script is asked first (``SCRIPT_FIRST``): a page in Arabic or Hebrew is read by its own model without the
        English readers' every line both ways up (most of its CPU), a page in Latin script goes on as before."""
        script: _ScriptReading | None = None
        if self.tesseract is not None:
            verdict = self.tesseract.read(image, lines[:EARLY_LINES], self.vocabulary)
            early = decided_early(verdict)
            if early.turn is not None:
                yield early, None
                return
            if len(lines) > EARLY_LINES:
                verdict = joined(verdict, self.tesseract.read(image, lines[EARLY_LINES:TESSERACT_LINES[0]],
                                                              self.vocabulary))
            if SCRIPT_FIRST and verdict.turn is None and not (verdict.first.real or verdict.second.real):
                script = self._script(image, lines)
                if script.model is not None:
                    yield verdict, None
                    yield script.read(self, lines), script.name
            start = TESSERACT_LINES[0]
            for batch in TESSERACT_LINES[1:]:
                if start >= len(lines) or verdict.turn is not None:
                    break
                verdict = joined(verdict, self.tesseract.read(image, lines[start:start + batch], self.vocabulary))
                start += batch
            yield verdict, None
        if self.recognizer is not None:
            yield self.recognizer.read(image, lines[:RECOGNIZER_LINES], self.vocabulary), None
        if script is None:
            script = self._script(image, lines)
            if script.model is not None:
                yield script.read(self, lines), script.name

    def _script(self, image: np.ndarray, lines: list[TextLine]) -> "_ScriptReading":
        """The script Tesseract's OSD sees on the strips of the first lines, and the model that reads it (None: no
        OSD or script models, a Latin script, or no model for it)."""
        if self.tesseract is None or self.tessdata is None or not self.tessdata.script_models:
            return _ScriptReading(None, None, [])
        strips = [cut_strip(image, ln, STRIP_HEIGHT) for ln in lines[:TESSERACT_LINES[0]]]
        name = self.tesseract.script(strip_page(strips)[0])
        model = SCRIPT_MODELS.get(name or "", name)
        usable = bool(name) and name not in LATIN_SCRIPTS and model in self.tessdata.script_models
        return _ScriptReading(name, model if usable else None, strips)

    def status(self) -> dict[str, object]:
        """What the readiness report says of the cue: its gate, readers and data, and where the data came from."""
        td = self.tessdata
        gate = self.detector.model
        return {"available": True, "enabled": True, "gate": str(gate.path), "gate_precision": gate.precision,
                "gate_detail": gate.detail,
                "readers": [r for r, on in (("tesseract", self.tesseract is not None),
                                            ("recognizer", self.recognizer is not None),
                                            ("script", bool(self.tesseract and td and td.script_models))) if on],
                "tessdata": str(td.folder) if td else None, "tessdata_source": td.source if td else None,
                "script_models": list(td.script_models) if td else [],
                "wordlists": self.vocabulary_source, "wordlist_words": len(self.vocabulary)}


SCRIPT_FIRST = True
"""Where Tesseract's English reads no word it knows on a page's first lines either way up, its script model is asked
before the other English readings (:meth:`TextCue._readings`)."""


@dataclass(frozen=True)
class _ScriptReading:
    """The script OSD saw on the first lines' strips (``name``), the Tesseract model that reads it (``model``; None
    when none does), and the strips ((``STRIP_HEIGHT``, w) uint8 each)."""

    name: str | None
    model: str | None
    strips: list[np.ndarray]

    def read(self, cue: "TextCue", lines: list[TextLine]) -> PairVerdict:
        """The strips read both ways up by ``model`` with English (``lines``: theirs, for the turns)."""
        return cue.tesseract.read_strips(self.strips, lines[0], cue.vocabulary, f"{self.model}+eng", "script")


QUARTER_TURN_PASS = True
"""When the lines a photo shows are read clearly neither way up, the gate looks at the photo turned 90 degrees and its
lines are read again: the detector finds small print running across its copy more surely than along it (the lines
of a receipt turned sideways came out as blocks), so a page turned sideways is often found whole only this way."""


def _turned_load(load: LoadImage) -> LoadImage:
    """``load`` for the image turned 90 degrees clockwise."""
    def turned(factor: float) -> tuple[np.ndarray, float]:
        image, actual = load(factor)
        return rotate_view(image, 90), actual
    return turned


def _turned_by(verdict: PairVerdict, quarter: int) -> PairVerdict:
    """``verdict`` of the image turned ``quarter`` degrees clockwise, as turns of the stored image."""
    if quarter == 0:
        return verdict
    shift = lambda r: replace(r, turn=(r.turn + quarter) % 360)  # noqa: E731
    return PairVerdict(shift(verdict.first), shift(verdict.second),
                       None if verdict.turn is None else (verdict.turn + quarter) % 360)


def _tesseract(tessdata: Tessdata | None) -> TesseractLines | None:
    if tessdata is None:
        return None
    try:
        return TesseractLines(tessdata.folder, tessdata.languages)
    except ImportError:  # tesserocr is a dependency; a broken install leaves the other reader
        return None


def _lines_image(gray: np.ndarray, lines: list[TextLine], load: LoadImage) -> tuple[np.ndarray, list[TextLine]]:
    """The image to cut ``lines``' strips from, and the lines in its px: ``gray`` when their letters are large enough
    there (``READ_MIN_LINE_PX``), else a larger decode."""
    height = statistics.median(ln.height for ln in lines)
    need = READ_MIN_LINE_PX / max(height, 1e-3)
    if need <= 1.0:
        return gray, lines
    image, factor = load(need)
    return image, [ln.scaled(factor) for ln in lines]


_LOCK = threading.Lock()


@lru_cache(maxsize=4)
def _cached(tessdata: Path | None, wordlists: Path | None) -> TextCue | str:
    try:
        vocabulary, source = find_vocabulary(wordlists)
        return TextCue(find_tessdata(tessdata), vocabulary, source)
    except (ImportError, OSError, RuntimeError) as exc:  # the gate's model or runtime missing
        return f"the text cue cannot start: {exc}"


def get_text_cue(tessdata: Path | None = None, wordlists: Path | None = None) -> TextCue | None:
    """The process's text cue for these data folders (None: the settings' or the default search), built once; None
    when it cannot run here."""
    with _LOCK:
        found = _cached(tessdata, wordlists)
    return found if isinstance(found, TextCue) else None


def text_status(enabled: bool = True, tessdata: Path | None = None, wordlists: Path | None = None) -> dict[str, object]:
    """What the readiness and engine reports say about the text cue."""
    if not enabled:
        return {"available": False, "enabled": False, "detail": "text cue switched off: faces only"}
    with _LOCK:
        found = _cached(tessdata, wordlists)
    if isinstance(found, str):
        return {"available": False, "enabled": True, "detail": f"{found}; faces only"}
    return found.status()


def text_settings_from_env() -> tuple[bool, Path | None, Path | None]:
    """(text cue on, Tesseract model folder, word-list folder) as the service passes them to its workers."""
    settings = worker_settings()
    return settings.orientation_text, settings.orientation_tessdata, settings.orientation_wordlists
