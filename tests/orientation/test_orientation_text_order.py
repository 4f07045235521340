"""The order in which the text cue's readers read a page: the cheapest first (Tesseract's first lines in two halves),
a page's own script model as soon as English reads nothing on it."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from workers.orientation.linereader import LineReading, PairVerdict
from workers.orientation.text import TextCue
from workers.orientation.textdata import Tessdata
from workers.orientation.textlines import TextLine

NOTHING = PairVerdict(LineReading("tesseract", 0), LineReading("tesseract", 180))


@dataclass
class Readers:
    """Stand-ins for Tesseract and the recogniser: what each was asked, in order; the script OSD sees; the turn each
    reader's reading decides (None: it reads nothing)."""

    script_seen: str
    decides: dict[str, int | None]
    asked: list[str] = field(default_factory=list)

    def read(self, image, lines, vocabulary, lang="eng", reader="tesseract"):
        self.asked.append(f"tesseract {len(lines)} lines")
        return self._verdict("tesseract")

    def script(self, page):
        self.asked.append("osd")
        return self.script_seen

    def read_strips(self, strips, line, vocabulary, lang="eng", reader="tesseract"):
        self.asked.append(f"{reader} {lang}")
        return self._verdict(reader)

    def _verdict(self, reader: str) -> PairVerdict:
        turn = self.decides.get(reader)
        if turn is None:
            return PairVerdict(LineReading(reader, 0), LineReading(reader, 180))
        return PairVerdict(LineReading(reader, turn, 9, 9, 3), LineReading(reader, (turn + 180) % 360), turn)


@dataclass
class Recogniser:
    readers: Readers

    def read(self, image, lines, vocabulary):
        self.readers.asked.append("recognizer")
        return self.readers._verdict("recognizer")


def _cue(readers: Readers) -> TextCue:
    cue = TextCue.__new__(TextCue)  # the readers alone: no gate, no models
    cue.tesseract, cue.recognizer, cue.vocabulary = readers, Recogniser(readers), frozenset()
    cue.tessdata = Tessdata(Path("/nowhere"), "setting", frozenset({"eng", "osd", "Arabic", "Hebrew"}))
    return cue


def _read(readers: Readers) -> list[PairVerdict]:
    image = np.full((400, 600), 255, np.uint8)
    lines = [TextLine((300.0, 20.0 + 15 * i), (1.0, 0.0), 400.0, 12.0, 0.9, "h") for i in range(24)]
    out = []
    for verdict, _ in _cue(readers)._readings(image, lines):
        out.append(verdict)
        if verdict.turn is not None:
            break
    return out


def test_a_page_english_reads_nothing_on_is_read_by_its_script_model_before_the_other_readers():
    readers = Readers("Arabic", {"script": 180})
    readings = _read(readers)
    assert readers.asked == ["tesseract 4 lines", "tesseract 4 lines", "osd", "script Arabic+eng"]
    assert readings[-1].turn == 180


def test_when_the_script_model_decides_nothing_the_english_readers_go_on_and_osd_is_not_asked_again():
    readers = Readers("Hebrew", {"recognizer": 90})
    _read(readers)
    assert readers.asked == ["tesseract 4 lines", "tesseract 4 lines", "osd", "script Hebrew+eng", "tesseract 16 lines",
                             "recognizer"]


def test_a_latin_page_english_reads_nothing_on_keeps_the_english_readers_order():
    readers = Readers("Latin", {})
    _read(readers)
    assert readers.asked == ["tesseract 4 lines", "tesseract 4 lines", "osd", "tesseract 16 lines", "recognizer"]


def test_a_page_english_reads_is_never_asked_for_its_script():
    readers = Readers("Arabic", {"tesseract": 0})
    _read(readers)
    assert readers.asked == ["tesseract 4 lines"]  # nine real words on three lines: the first half decides


def test_the_first_lines_without_a_wide_margin_are_read_with_the_rest_of_the_batch():
    readers = Readers("Arabic", {"tesseract": 0})
    readers._verdict = lambda reader: PairVerdict(LineReading(reader, 0, 4, 4, 2), LineReading(reader, 180))
    readings = _read(readers)
    assert readers.asked == ["tesseract 4 lines", "tesseract 4 lines"]  # 4 real words, then 8 on the batch: decided
    assert readings[-1].turn == 0 and readings[-1].first.real == 8
