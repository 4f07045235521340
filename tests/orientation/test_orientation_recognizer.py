"""The PP-OCR line recogniser run as PaddleOCR runs it: its input, its CTC decoding, and a line it reads."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from workers.orientation.linereader import RecognizerLines, ctc_decode, recognizer_input


def test_ctc_decoding_merges_repeats_drops_blanks_and_averages_the_kept_steps():
    characters = ("", "a", "b", " ")
    steps = [(0, 0.9), (1, 0.8), (1, 0.6), (0, 0.7), (1, 0.5), (2, 0.4), (2, 0.99), (3, 0.3)]  # (class, probability)
    probabilities = np.full((len(steps), len(characters)), 0.01, np.float32)
    for t, (c, p) in enumerate(steps):
        probabilities[t, c] = p
    text, confidence = ctc_decode(probabilities, characters)
    assert text == "aab "  # a a -> a; the blank parts the two a's; b b -> b
    assert confidence == pytest.approx(np.mean([0.8, 0.5, 0.4, 0.3]), abs=1e-5)
    assert ctc_decode(np.eye(4, dtype=np.float32)[[0, 0]], characters) == ("", 0.0)  # blanks only


def test_a_strip_becomes_48_px_high_at_least_320_wide_padded_with_mid_grey():
    strip = np.full((24, 60), 255, np.uint8)
    x = recognizer_input(strip)
    assert x.shape == (1, 3, 48, 320) and x.dtype == np.float32
    assert np.all(x[0, :, :, :120] == 1.0) and np.all(x[0, :, :, 120:] == 0.0)  # white, then padding
    long = recognizer_input(np.zeros((48, 500), np.uint8))
    assert long.shape == (1, 3, 48, 500) and np.all(long == -1.0)


def test_the_recogniser_reads_a_printed_line_the_right_way_up_only():
    strip = np.full((48, 420), 255, np.uint8)
    cv2.putText(strip, "ORANGE JUICE", (8, 36), cv2.FONT_HERSHEY_SIMPLEX, 1.1, 0, 2, cv2.LINE_AA)
    reader = RecognizerLines()
    text, confidence = reader.line(strip)
    assert text.replace(" ", "").upper() == "ORANGEJUICE" and confidence > 0.8
    upside_down, _ = reader.line(cv2.rotate(strip, cv2.ROTATE_180))
    assert "ORANGE" not in upside_down.upper()
