"""Which OCR words are real words (issue 33: the text cue decides only on evidence that is text)."""
from __future__ import annotations

import pytest

from workers.orientation.words import OcrWord, known, real_words, word_lists

VOCABULARY = frozenset({"receipt", "total", "paris", "louvre", "lilt", "tilt"})


def w(text: str, conf: float = 92.0, box=(10, 10, 80, 20), dictionary: bool | None = None) -> OcrWord:
    return OcrWord(text, conf, tuple(float(v) for v in box), dictionary)


def test_real_words_are_confident_known_horizontal_and_of_one_size():
    found = real_words([w("Receipt"), w("TOTAL:"), w("Paris", 70.0),  # not confident
                        w("xqzv"),  # known to no dictionary
                        w("tot"),  # too short
                        w("lilt"), w("tilt"),  # strokes only: what lines read as
                        w("Louvre", box=(0, 0, 20, 80)),  # taller than wide: not along the reading direction
                        w("Paris", box=(0, 0, 400, 200))],  # ten times the others' height: not on their lines
                       VOCABULARY)
    assert [x.text for x in found] == ["Receipt", "TOTAL:"]


def test_dense_scripts_are_known_by_tesseracts_dictionary_from_two_characters():
    assert known(w("禁止", dictionary=True), VOCABULARY) and not known(w("禁止", dictionary=False), VOCABULARY)
    assert [x.text for x in real_words([w("禁止", dictionary=True, box=(0, 0, 40, 20)), w("禁", dictionary=True)])] \
        == ["禁止"]
    # Tesseract's flag alone does not make a Latin word known: it flags strings read from textures
    assert not known(w("RTA", dictionary=True), VOCABULARY)


def test_a_script_no_word_list_holds_is_known_by_tesseracts_dictionary():
    # Debian ships no Hebrew or Arabic word list: the script model's dictionary decides, from four letters
    assert known(w("שלום", dictionary=True), VOCABULARY) and not known(w("שלום", dictionary=False), VOCABULARY)
    assert known(w("(محمد)", dictionary=True), VOCABULARY)
    assert [x.text for x in real_words([w("שלום", dictionary=True), w("של", dictionary=True)], VOCABULARY)] == ["שלום"]
    # once a word list of the script is installed, it decides, as for Latin
    with_hebrew = VOCABULARY | {"שלום"}
    assert known(w("שלום", dictionary=False), with_hebrew) and not known(w("שלוס", dictionary=True), with_hebrew)
    assert known(w("Paris", dictionary=False), with_hebrew)


def test_word_lists_are_read_from_a_folder(tmp_path):
    (tmp_path / "english").write_bytes(b"Receipt \r\nTOTAL\n\n")  # spaces, CRLF and case do not matter
    (tmp_path / "README.select-wordlist").write_text("not words\n")
    (tmp_path / "words").symlink_to(tmp_path / "english")
    assert word_lists(tmp_path) == frozenset({"receipt", "total"})
    assert word_lists(tmp_path / "missing") == frozenset()


@pytest.mark.skipif(not word_lists(__import__("pathlib").Path("/usr/share/dict")),
                    reason="no word lists in /usr/share/dict (apt-get install wamerican)")
def test_the_installed_word_lists_know_common_words():
    vocabulary = word_lists(__import__("pathlib").Path("/usr/share/dict"))
    assert {"receipt", "total", "thank"} <= vocabulary


def test_a_vocabulary_knows_its_words_and_scripts_and_nothing_else():
    from workers.orientation.words import Vocabulary, scripts_of

    words = {"receipt", "total", "straße", "שלום"}
    vocabulary = Vocabulary.of(words)
    assert len(vocabulary) == 4 and all(w in vocabulary for w in words)
    assert "Receipt" not in vocabulary and "receipts" not in vocabulary and "" not in vocabulary and 7 not in vocabulary
    assert scripts_of(vocabulary) == scripts_of(frozenset(words)) == {"LATIN", "HEBREW"}
    hebrew = OcrWord("שלום", 95.0, (0, 0, 40, 10))
    assert known(hebrew, vocabulary) and known(OcrWord("Total:", 95.0), vocabulary)
