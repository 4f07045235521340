"""Reading a photo's text lines both ways up: which way is up, from words a dictionary knows.

The gate (:mod:`workers.orientation.textlines`) gives lines and the axis each runs along, so two turns remain per
axis: the lines read as cut out (each strip's reading direction pointing right) or turned 180 degrees. Each reader
reads the same strips both ways, and the words a dictionary knows (:func:`workers.orientation.words.real_words`)
decide (:func:`decide_pair`): text read right gives many of them, read upside down next to none.

Readers, cheapest first (:class:`workers.orientation.text.TextCue` runs them in turn until one decides):

- :class:`TesseractLines`: Tesseract's English LSTM on a page made of the strips (one call each way; tens of ms);
- :class:`RecognizerLines`: PaddleOCR's multilingual PP-OCRv6 recogniser (in the ``rapidocr`` wheel), which reads
  photographed and styled text (signs, posters, screens) Tesseract misses, at several times its cost, on fewer lines;
- :class:`TesseractLines` with a script model (Korean, Japanese, Chinese, Thai, Arabic, Hebrew, ...: Debian's
  ``tesseract-ocr-script-*``, optional), chosen by Tesseract's script detection on the strips' page.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import AbstractSet, Literal, Sequence

import cv2
import numpy as np

from workers.common.denormals import flushed_denormals
from workers.orientation.textlines import TextLine
from workers.orientation.words import Lexicon, OcrWord, confident, real_words

Reader = Literal["tesseract", "recognizer", "script"]

STRIP_HEIGHT = 32
"""Height (px) of a line strip Tesseract reads (its LSTM models were trained on lines of about this height)."""
STRIP_GAP = 16
"""White space (px) between and around the strips on the page Tesseract reads."""
RECOGNIZER_HEIGHT = 48
"""Height (px) of the strips the PP-OCR recogniser reads (its input height)."""
RECOGNIZER_WIDTH = 320
"""Least width (px) of its input (PaddleOCR's ``rec_image_shape`` 3 x 48 x 320): a shorter strip is padded."""
RECOGNIZER_MODEL = "PP-OCRv6_rec_small.onnx"
TESSERACT_LINES = (8, 16)
"""The batches of lines of one axis Tesseract reads, in turn, until the readings so far decide (the longest and surest
first): 8 lines decide most pages; a receipt's long lines are often numbers and codes, so 16 more may be read."""
STRIP_FILL = 0.85
"""A strip takes this share of its line's rectangle across the line (centred): DB's rectangles of close lines
overlap, and a strip with the edges of the neighbouring lines in it reads worse."""
RECOGNIZER_LINES = 4
"""Most lines of one axis the recogniser reads (it costs several times Tesseract's per line)."""
RECOGNIZER_MAX_ASPECT = 16.0
"""... and of each, the first this many heights (a sign's line is shorter; a page's first words are enough)."""
STRIP_MAX_ASPECT = 40.0
"""A strip longer than this many times its height is cut to that length: a line of a page wide scan holds enough
words in its first part, and the reading cost grows with the length."""
MIN_REAL = 3
"""Least real words (:func:`workers.orientation.words.real_words`) a reading must hold to decide ..."""
RATIO = 3.0
"""... this many times the real words of the same strips read the other way up (at least 1 counted there) ..."""
MIN_LINES = 2
"""... on at least this many different lines (one line of words can be a sign's border pattern or a logo)."""
CONFIDENT_MIN = 6
"""Or: least confident words of letters (:func:`confident_word`, in a dictionary or not) a reading must hold to decide
(text in a language no word list holds: Latin, old spellings, Hindi, Arabic read by its script model), ..."""
CONFIDENT_LINES = 3
"""... on at least this many lines, ..."""
CONFIDENT_RATIO = 4.0
"""... this many times the confident words of the same strips read the other way up (at least 1 counted there).
Strips are text lines the detector found, read upside down they give next to no confident word of four letters; the
stricter counts than the real-word rule's stand for the dictionary's check."""
EARLY_LINES = 4
"""Tesseract reads the first batch of lines in two halves: the first this many lines decide alone only by a wide
margin (:func:`decided_early`), else the rest of the batch is read and the whole batch decides by the rule above. Most
text photos read many real words one way up and next to none the other on their first lines: half the reading."""
EARLY_MIN_REAL = 2 * MIN_REAL
"""The wide margin: at least this many real words on ``MIN_LINES`` lines, ..."""
EARLY_RATIO = 2 * RATIO
"""... and this many times the other way up's (at least 1 counted there); the confident-word rule does not decide
early."""


@dataclass(frozen=True)
class LineReading:
    """The strips of one axis read one way: ``turn`` is the clockwise rotation of the stored image this reading says
    makes it upright; ``real`` the real words read and ``lines`` on how many strips they lie."""

    reader: Reader
    turn: int
    words: int = 0
    real: int = 0
    lines: int = 0
    sample: tuple[str, ...] = ()
    confident: int = 0
    """Confident words of letters (:func:`confident_word`), in a dictionary or not."""
    confident_lines: int = 0
    """On how many strips they lie."""
    """Up to a few of the real words (for people: what was read)."""


@dataclass(frozen=True)
class PairVerdict:
    """Two readings of the same strips, turned 180 degrees apart, and what they decide."""

    first: LineReading
    second: LineReading
    turn: int | None = None
    """The turn they decide (None: neither reads clearly more real words)."""


def turn_of(line: TextLine, flipped: bool) -> int:
    """Clockwise degrees that show the stored image upright when ``line``'s strip reads right as cut out (``flipped``
    False) or turned 180 degrees (True). A strip is cut with the line's direction pointing right: a horizontal line
    (direction right) reads right as stored; a vertical one (direction down) needs the image turned 270 degrees."""
    base = 0 if line.axis == "h" else 270
    return (base + (180 if flipped else 0)) % 360


def cut_strip(gray: np.ndarray, line: TextLine, height: int, max_aspect: float = STRIP_MAX_ASPECT) -> np.ndarray:
    """``line``'s rectangle (its middle ``STRIP_FILL`` across) cut from ``gray`` ((H, W) uint8; the line in its px)
    as a (``height``, w) uint8 strip that runs along the line's direction (w = the line's length scaled like its
    height, at most ``max_aspect`` heights)."""
    line = TextLine(line.center, line.direction, line.length, line.height * STRIP_FILL, line.score, line.axis)
    scale = height / max(line.height, 1.0)
    width = int(round(min(line.length * scale, max_aspect * height)))
    width = max(width, 8)
    quad = line.quad
    if width < line.length * scale:  # keep the line's start: the strip is cut at its far end
        quad = quad.copy()
        along = (quad[1] - quad[0]) * (width / (line.length * scale))
        quad[1], quad[2] = quad[0] + along, quad[3] + along
    target = np.float32([[0, 0], [width, 0], [width, height], [0, height]])
    matrix = cv2.getPerspectiveTransform(quad, target)
    interpolation = cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC
    return cv2.warpPerspective(gray, matrix, (width, height), flags=interpolation, borderMode=cv2.BORDER_REPLICATE)


def dark_on_light(strip: np.ndarray) -> np.ndarray:
    """``strip`` ((h, w) uint8) as dark text on a white ground: inverted when most of it is dark (light text on a dark
    sign), then stretched so that its ground (95th percentile) is white and its ink (5th) black. Tesseract binarises
    the whole page of strips with one threshold: a strip on grey paper beside the page's white gaps went black."""
    if float(np.median(strip)) < 110:
        strip = 255 - strip
    ink, ground = np.percentile(strip, (5, 95))
    if ground - ink < 8:  # a flat strip: nothing to stretch
        return strip
    stretched = (strip.astype(np.float32) - ink) * (255.0 / (ground - ink))
    return np.clip(stretched, 0, 255).astype(np.uint8)


def strip_page(strips: Sequence[np.ndarray], gap: int = STRIP_GAP) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """The strips (each (h, w) uint8, one height) stacked on one white page, dark text on light, with ``gap`` px
    around each; and each strip's (top, bottom) row on the page."""
    height = max(s.shape[0] for s in strips)
    width = max(s.shape[1] for s in strips) + 2 * gap
    page = np.full((len(strips) * (height + gap) + gap, width), 255, np.uint8)
    rows = []
    for i, s in enumerate(strips):
        top = gap + i * (height + gap)
        page[top:top + s.shape[0], gap:gap + s.shape[1]] = dark_on_light(s)
        rows.append((top, top + height))
    return page, rows


def _line_of(word: OcrWord, rows: Sequence[tuple[int, int]]) -> int:
    middle = word.box[1] + word.box[3] / 2
    return next((i for i, (top, bottom) in enumerate(rows) if top - STRIP_GAP / 2 <= middle <= bottom + STRIP_GAP / 2),
                -1)


def summarise(reader: Reader, turn: int, words: Sequence[OcrWord], line_of: Sequence[int],
              vocabulary: Lexicon) -> LineReading:
    """One reading summed up: ``words`` (each on the strip ``line_of`` says) with ``vocabulary`` (lower case)."""
    real = real_words(words, vocabulary)
    index = {id(w): i for w, i in zip(words, line_of)}
    lines = {index[id(w)] for w in real}
    sure = [w for w in words if confident_word(w)]
    return LineReading(reader, turn, sum(any(ch.isalpha() for ch in w.text) for w in words), len(real), len(lines),
                       tuple(w.text for w in real[:6]), len(sure), len({index[id(w)] for w in sure}))


def confident_word(word: OcrWord) -> bool:
    """A word read confidently and made of letters (at least 4, two different, not strokes only), whether a dictionary
    knows it or not: what text read the right way up gives in any language."""
    letters = {ch for ch in word.text.lower() if ch.isalpha()}
    return confident(word, 4) and len(letters) >= 2 and not letters <= set("iljtf")


def joined(a: PairVerdict, b: PairVerdict) -> PairVerdict:
    """Two pairs of readings of different strips of one axis by one reader, summed up and decided as one."""
    def add(x: LineReading, y: LineReading) -> LineReading:
        return LineReading(x.reader, x.turn, x.words + y.words, x.real + y.real, x.lines + y.lines,
                           (x.sample + y.sample)[:6], x.confident + y.confident, x.confident_lines + y.confident_lines)
    return decide_pair(add(a.first, b.first), add(a.second, b.second))


def decided_early(verdict: PairVerdict) -> PairVerdict:
    """``verdict`` (the first ``EARLY_LINES`` lines of a batch) decided by the wide margin of ``EARLY_MIN_REAL`` and
    ``EARLY_RATIO`` alone (turn None when it does not decide so)."""
    return decide_pair(verdict.first, verdict.second, EARLY_MIN_REAL, EARLY_RATIO, confident=False)


def decide_pair(first: LineReading, second: LineReading, min_real: int = MIN_REAL, ratio: float = RATIO,
                min_lines: int = MIN_LINES, confident: bool = True) -> PairVerdict:
    """The turn two readings of the same strips 180 degrees apart decide: the one with at least ``min_real`` real
    words on ``min_lines`` lines and ``ratio`` times the other's real words (at least 1 counted there); or, failing
    that, with ``CONFIDENT_MIN`` confident words on ``CONFIDENT_LINES`` lines and ``CONFIDENT_RATIO`` times the
    other's, while the other reads no more real words (``confident`` False: the real-word rule alone)."""
    for a, b in ((first, second), (second, first)):
        if a.real >= min_real and a.lines >= min_lines and a.real >= ratio * max(b.real, 1):
            return PairVerdict(first, second, a.turn)
    for a, b in ((first, second), (second, first)) if confident else ():
        if (a.confident >= CONFIDENT_MIN and a.confident_lines >= CONFIDENT_LINES
                and a.confident >= CONFIDENT_RATIO * max(b.confident, 1) and a.real >= b.real):
            return PairVerdict(first, second, a.turn)
    return PairVerdict(first, second, None)


class TesseractLines:
    """Tesseract (through ``tesserocr``) reading a page of line strips, in English or a script model plus English;
    and its script detection (OSD) on that page. One Tesseract API object per thread and language."""

    def __init__(self, tessdata: Path, languages: AbstractSet[str]) -> None:
        import tesserocr

        self._tesserocr = tesserocr
        self.tessdata = Path(tessdata)
        self.languages = frozenset(languages)
        self._local = threading.local()

    def _api(self, lang: str):
        apis = self._local.__dict__.setdefault("apis", {})
        if lang not in apis:
            tesserocr = self._tesserocr
            if lang == "osd":
                api = tesserocr.PyTessBaseAPI(path=str(self.tessdata), lang="osd", psm=tesserocr.PSM.OSD_ONLY)
                api.SetVariable("min_characters_to_try", "20")
            else:
                api = tesserocr.PyTessBaseAPI(path=str(self.tessdata), lang=lang, psm=tesserocr.PSM.SINGLE_BLOCK)
                # The strips are dark on light already (strip_page): Tesseract's second reading of every line it
                # reads poorly, inverted, only costs time (most lines of a page read the wrong way up are poor).
                api.SetVariable("tessedit_do_invert", "0")
            apis[lang] = api
        return apis[lang]

    def words(self, page: np.ndarray, lang: str = "eng") -> list[OcrWord]:
        """Every word Tesseract reads on ``page`` ((H, W) uint8): text, confidence 0-100, box (x, y, w, h) in page px,
        and whether the language's dictionary accepts it."""
        from PIL import Image

        tesserocr = self._tesserocr
        api = self._api(lang)
        api.SetImage(Image.fromarray(page))
        api.SetSourceResolution(300)
        with flushed_denormals():
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

    def script(self, page: np.ndarray) -> str | None:
        """The script Tesseract's OSD sees on ``page`` ((H, W) uint8; ``Latin``, ``Han``, ``Hangul``, ``Arabic``,
        ...), or None (no ``osd`` data, too few characters)."""
        from PIL import Image

        if "osd" not in self.languages:
            return None
        api = self._api("osd")
        api.SetImage(Image.fromarray(page))
        api.SetSourceResolution(300)
        with flushed_denormals():
            found = api.DetectOrientationScript()
        return found.get("script_name") if found else None

    def read(self, gray: np.ndarray, lines: Sequence[TextLine], vocabulary: Lexicon, lang: str = "eng",
             reader: Reader = "tesseract") -> PairVerdict:
        """``lines`` (one axis, px of ``gray``) read both ways up in ``lang``."""
        strips = [cut_strip(gray, ln, STRIP_HEIGHT) for ln in lines]
        return self.read_strips(strips, lines[0], vocabulary, lang, reader)

    def read_strips(self, strips: Sequence[np.ndarray], line: TextLine, vocabulary: Lexicon,
                    lang: str = "eng", reader: Reader = "tesseract") -> PairVerdict:
        """Strips cut from lines of ``line``'s axis, read as cut and turned 180 degrees."""
        readings = []
        for flipped in (False, True):
            page, rows = strip_page([cv2.rotate(s, cv2.ROTATE_180) if flipped else s for s in strips])
            words = self.words(page, lang)
            readings.append(summarise(reader, turn_of(line, flipped), words, [_line_of(w, rows) for w in words],
                                      vocabulary))
        return decide_pair(*readings)


@dataclass
class RecognizerLines:
    """PaddleOCR's PP-OCRv6 multilingual line recogniser (the model in the ``rapidocr`` wheel), run with onnxruntime
    on one core as PaddleOCR runs it (:func:`recognizer_input`, :func:`ctc_decode`; its alphabet is in the model's
    metadata). Built in a tenth of a second, where rapidocr's own wrapper took about 0.6 s of every process that
    reads text (its configuration files) for the same readings. Not run with denormals flushed
    (:mod:`workers.common.denormals`): unlike the gate and Tesseract it costs the same either way (22 ms a strip on an
    Intel Xeon). Thread-safe (onnxruntime sessions may be run from several threads)."""

    _session: object = field(default=None, repr=False)

    def __post_init__(self) -> None:
        from workers.orientation.quantize import one_core_session
        from workers.orientation.textlines import model_path

        self._session = one_core_session(model_path(RECOGNIZER_MODEL, "text recogniser"))
        self._input = self._session.get_inputs()[0].name
        alphabet = self._session.get_modelmeta().custom_metadata_map["character"].splitlines()
        self._characters = ("", *alphabet, " ")  # CTC's blank first; PaddleOCR adds the space last

    def line(self, strip: np.ndarray) -> tuple[str, float]:
        """(text, confidence 0-1) of one strip ((h, w) uint8 grey)."""
        probabilities = self._session.run(None, {self._input: recognizer_input(strip)})[0][0]
        return ctc_decode(probabilities, self._characters)

    def read(self, gray: np.ndarray, lines: Sequence[TextLine], vocabulary: Lexicon) -> PairVerdict:
        """``lines`` (one axis, px of ``gray``) read both ways up; each line's words carry its confidence."""
        strips = [cut_strip(gray, ln, RECOGNIZER_HEIGHT, RECOGNIZER_MAX_ASPECT) for ln in lines]
        readings = []
        for flipped in (False, True):
            words, line_of = [], []
            for i, s in enumerate(strips):
                text, score = self.line(cv2.rotate(s, cv2.ROTATE_180) if flipped else s)
                words += _split(text, score, RECOGNIZER_HEIGHT)
                line_of += [i] * (len(words) - len(line_of))
            readings.append(summarise("recognizer", turn_of(lines[0], flipped), words, line_of, vocabulary))
        return decide_pair(*readings)


def recognizer_input(strip: np.ndarray) -> np.ndarray:
    """The recogniser's input (1, 3, 48, W) float32 in [-1, 1] for ``strip`` ((h, w) uint8 grey): resized to
    ``RECOGNIZER_HEIGHT`` px high (bilinear, its width rounded up), at least ``RECOGNIZER_WIDTH`` px wide, padded on
    the right with zeros (mid grey), the grey in all three channels (PaddleOCR's ``resize_norm_img``)."""
    h, w = strip.shape[:2]
    ratio = w / float(h)
    width = int(RECOGNIZER_HEIGHT * max(RECOGNIZER_WIDTH / RECOGNIZER_HEIGHT, ratio))
    resized_w = min(width, int(math.ceil(RECOGNIZER_HEIGHT * ratio)))
    resized = cv2.resize(strip, (resized_w, RECOGNIZER_HEIGHT)).astype(np.float32)
    x = np.zeros((1, 3, RECOGNIZER_HEIGHT, width), np.float32)
    x[0, :, :, :resized_w] = (resized / 255 - 0.5) / 0.5
    return x


def ctc_decode(probabilities: np.ndarray, characters: Sequence[str]) -> tuple[str, float]:
    """(text, confidence 0-1) of a CTC output ((T, C) float32, each step's probability of each class; class 0 the
    blank): each step's likeliest class, repeats merged, blanks dropped; the confidence is the mean probability of
    the kept steps (0 for none), rounded to 5 places as PaddleOCR rounds it."""
    best = probabilities.argmax(axis=1)
    keep = np.ones(len(best), bool)
    keep[1:] = best[1:] != best[:-1]
    keep &= best != 0
    text = "".join(characters[i] for i in best[keep])
    confidences = [round(p, 5) for p in probabilities.max(axis=1)[keep].tolist()] or [0]
    return text, float(np.mean(confidences).round(5))


def _split(text: str, score: float, height: int) -> list[OcrWord]:
    """A recognised line's words, each with the line's confidence (0-100) and a box as wide as its letters (about half
    a strip height each), so the geometric tests of :func:`workers.orientation.words.real_words` hold for them."""
    out, x = [], 0.0
    for token in text.split():
        width = 0.5 * height * len(token)
        out.append(OcrWord(token, 100.0 * score, (x, 0.0, width, float(height)), None))
        x += width + 0.25 * height
    return out
