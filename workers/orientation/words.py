"""What counts as text: the words an OCR reading found, sorted into real words and noise.

The text cue may decide only on evidence that is text. Tesseract reads "words" in anything: gravel, fields seen from
above, fabric. Such readings are single letters, runs of ``lll``/``iii`` or letter soup at high confidence, scattered
in every direction. A *real word* (:func:`real_words`) is one that

- Tesseract read confidently (``TEXT_WORD_MIN_CONFIDENCE``), made mostly of letters, at least
  ``REAL_WORD_MIN_LETTERS`` of them (two for the scripts whose words are one or two characters: CJK, Hangul, Thai);
- a dictionary knows: for an alphabetic script the word lists installed for people hold words of (Debian's
  ``wamerican``, ``wngerman``, ``wfrench``, ...: every file in ``SWEEPCAST_ORIENTATION_WORDLISTS``, default
  ``/usr/share/dict``), those word lists; for the dense scripts, and for a script no installed word list holds
  (Debian ships none for Hebrew or Arabic), the reading script model's own dictionary (Tesseract's word DAWG,
  ``WordIsFromDictionary``; only through tesserocr). Tesseract's flag is not used where word lists exist: read with
  a script model first, "LITTER" and "CITY" were not flagged, and it flags strings such as "np", "RTA" or "DAE"
  read from textures or sideways;
- is not made of vertical strokes only (``i``, ``l``, ``j``, ``t``, ``f``: what a pattern of lines reads as), and has
  two different letters at least;
- lies along the reading direction: its box is wider than tall, as a horizontal word of two or more letters is;
- stands on a line of the same size as the view's other real words (its height within ``REAL_WORD_HEIGHT_RATIO`` of
  their median): lines of text have one letter size; noise read as words comes in every size.

The line reader (:mod:`workers.orientation.linereader`) counts the real words of a reading each way up: text read
upright reads as nonsense upside down.
"""
from __future__ import annotations

import hashlib
import re
import statistics
import unicodedata
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import AbstractSet, Iterable, Union

import numpy as np

from workers.orientation.geometry import Box

TEXT_WORD_MIN_CONFIDENCE = 80.0
"""A word counts when Tesseract's word confidence (0-100) reaches this (chosen a priori: Tesseract's own "good word"
region; not tuned)."""
TEXT_WORD_LETTER_SHARE = 0.6
"""... and letters make up at least this share of it (a priori: numbers and punctuation read from noise are not
words)."""
REAL_WORD_MIN_LETTERS = 4
"""Least letters of a real word in an alphabetic script. Short strings are what noise reads, and the dictionaries
know most of them: Hebrew read sideways by the English model gave ten three-letter words the word lists or
Tesseract accept ("ere", "par", "aga", "RTA", "DAE"), more than it read upright."""
REAL_WORD_MIN_LETTERS_DENSE = 2
"""Least letters of a real word in the scripts that write a word with one or two characters (CJK, Hangul, Thai)."""
REAL_WORD_HEIGHT_RATIO = 2.5
"""A real word's box height is within this factor of the median height of the view's real words."""
_STROKES = frozenset("iljtf")
_NON_LATIN_FROM = 0x0370
"""Code points from Greek upwards are not Latin (Latin, its extensions and IPA lie below)."""
_BEYOND_LATIN = re.compile(f"[^\\x00-{chr(_NON_LATIN_FROM - 1)}]")
_DENSE_SCRIPTS_FROM = 0x0E00
"""Code points from Thai upwards (Thai, Hangul, CJK, kana) are the dense scripts; Latin, Greek, Cyrillic, Hebrew and
Arabic lie below."""


@dataclass(frozen=True)
class OcrWord:
    """One word of an OCR reading.

    ``box`` is (x, y, w, h) in pixels of the page as it was read (the turned view); ``dictionary`` whether the
    language model's dictionary accepts the word (None: the backend cannot say)."""

    text: str
    confidence: float
    box: Box = (0.0, 0.0, 0.0, 0.0)
    dictionary: bool | None = None


@lru_cache(maxsize=4)
def word_lists(folder: Path) -> frozenset[str]:
    """Every word (lower case) of the word lists in ``folder`` (one word a line, UTF-8; README files skipped); empty
    when there is none."""
    words: set[str] = set()
    folder = Path(folder)
    if not folder.is_dir():
        return frozenset()
    seen = set()
    for path in sorted(folder.iterdir()):
        real = path.resolve()
        if real in seen or not real.is_file() or path.name.upper().startswith("README"):
            continue
        seen.add(real)
        try:
            # one lower() over the whole file and strip() mapped over its lines: a third less than a generator of
            # line.strip().lower() over Debian's 790,000 words (0.33 against 0.50 s), the same words
            words.update(map(str.strip, real.read_text(encoding="utf-8", errors="ignore").lower().splitlines()))
        except OSError:
            continue
    words.discard("")
    return frozenset(words)


def _core(text: str) -> str:
    """The word without the punctuation OCR reads around it ("Total:", "(EUR)")."""
    return text.strip(".,:;!?()[]{}\"'`-_/|*")


class Vocabulary:
    """Words (lower case) looked up by a 64-bit hash of each (BLAKE2b of the UTF-8 bytes): a sorted (n,) uint64 array
    ``hashes`` and the scripts the words hold letters of (``scripts``, as :func:`scripts_of` says). Debian's 790,000
    words as a Python set cost each process that reads text half a second to build (0.2 s to unpickle), and their
    scripts 0.1 s more; as this array they load from the model cache in milliseconds
    (:func:`workers.orientation.textdata.find_vocabulary`). Two strings share a hash with a chance of about 1 in
    2^64 per pair: a string read from noise that is no word is taken for one of 790,000 words about once in 2e13
    lookups."""

    def __init__(self, hashes: np.ndarray, scripts: frozenset[str]) -> None:
        self.hashes = hashes
        self.scripts = scripts

    @classmethod
    def of(cls, words: Iterable[str]) -> "Vocabulary":
        """The vocabulary of ``words`` (lower case)."""
        words = frozenset(words)
        digests = b"".join(_digest(w) for w in words)
        return cls(np.unique(np.frombuffer(digests, "<u8")), _scripts_of(words))

    def __contains__(self, word: object) -> bool:
        if not isinstance(word, str):
            return False
        h = np.uint64(int.from_bytes(_digest(word), "little"))
        i = int(np.searchsorted(self.hashes, h))
        return i < len(self.hashes) and self.hashes[i] == h

    def __len__(self) -> int:
        return len(self.hashes)


def _digest(word: str) -> bytes:
    """The 8 bytes of ``word``'s hash (little-endian; the same in every process, unlike ``hash``)."""
    return hashlib.blake2b(word.encode("utf-8", "surrogatepass"), digest_size=8).digest()


Lexicon = Union[AbstractSet[str], Vocabulary]
"""The words a dictionary check looks in: a set of words, or a :class:`Vocabulary`."""


def scripts_of(lexicon: Lexicon) -> frozenset[str]:
    """The scripts ``lexicon``'s words hold letters of (``LATIN`` always)."""
    return lexicon.scripts if isinstance(lexicon, Vocabulary) else _scripts_of(frozenset(lexicon))


def known(word: OcrWord, vocabulary: Lexicon) -> bool:
    """A dictionary knows ``word``: the word lists (``vocabulary``, lower case; punctuation around the word stripped)
    when they hold words of its script, else Tesseract's own (the dense scripts always)."""
    script = _script(word.text)
    if _is_dense(word.text) or (script != "LATIN" and script not in scripts_of(vocabulary)):
        return word.dictionary is True
    return _core(word.text).lower() in vocabulary


def letter_count(text: str) -> int:
    return sum(ch.isalpha() for ch in text)


def _script(text: str) -> str:
    """The script of ``text``'s first letter beyond Latin (the first word of its Unicode name: ``GREEK``, ``CYRILLIC``,
    ``HEBREW``, ``ARABIC``, ...), else ``LATIN``."""
    for ch in text:
        if ch.isalpha() and ord(ch) >= _NON_LATIN_FROM:
            return unicodedata.name(ch, "UNKNOWN").split(" ", 1)[0]
    return "LATIN"


@lru_cache(maxsize=4)
def _scripts_of(vocabulary: AbstractSet[str]) -> frozenset[str]:
    """The scripts the word lists hold letters of (``LATIN`` always: the English OCR's words are looked up in them,
    installed or not). One pass of a regular expression over the words joined (a tenth of a second for Debian's
    800,000 words, where a loop over the words took half a second of each worker's first text photo)."""
    letters = set(_BEYOND_LATIN.findall("\n".join(vocabulary)))
    return frozenset({"LATIN"} | {_script(ch) for ch in letters if ch.isalpha()})


def _is_dense(text: str) -> bool:
    return any(ch.isalpha() and ord(ch) >= _DENSE_SCRIPTS_FROM for ch in text)


def confident(word: OcrWord, min_letters: int) -> bool:
    """Confident and made of letters: at least ``min_letters`` of them, ``TEXT_WORD_LETTER_SHARE`` of the word."""
    letters = letter_count(word.text)
    return (word.confidence >= TEXT_WORD_MIN_CONFIDENCE and letters >= min_letters
            and letters >= TEXT_WORD_LETTER_SHARE * len(word.text))


def real_words(words: Iterable[OcrWord], vocabulary: Lexicon = frozenset()) -> list[OcrWord]:
    """The real words of one reading (module docstring): confident, known to a dictionary (``vocabulary``: the word
    lists, lower case; or Tesseract's flag), not strokes only, horizontal, and on lines of one letter size."""
    found = []
    for w in words:
        least = REAL_WORD_MIN_LETTERS_DENSE if _is_dense(w.text) else REAL_WORD_MIN_LETTERS
        letters = {ch for ch in w.text.lower() if ch.isalpha()}
        if (confident(w, least) and known(w, vocabulary) and len(letters) >= 2 and not letters <= _STROKES
                and w.box[2] >= w.box[3] > 0):
            found.append(w)
    if len(found) < 2:
        return found
    median = statistics.median(w.box[3] for w in found)
    return [w for w in found if median / REAL_WORD_HEIGHT_RATIO <= w.box[3] <= median * REAL_WORD_HEIGHT_RATIO]


