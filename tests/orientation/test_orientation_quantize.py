"""The text-line gate's 8-bit model: built from rapidocr's, checked against it, used only where it pays."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.orientation.test_orientation_text import text_page
from workers.orientation import quantize
from workers.orientation.geometry import rotate_view
from workers.orientation.textlines import LineDetector, model_path, network_input


def _to_input(page: np.ndarray) -> np.ndarray:
    return network_input(page, max(page.shape))[0]


def test_the_calibration_pages_are_the_same_every_time_and_at_the_gates_size():
    first, again = list(quantize.calibration_pages(6)), list(quantize.calibration_pages(6))
    assert all(np.array_equal(a, b) for a, b in zip(first, again))
    assert {p.shape for p in first} == {(352, 480), (480, 352)} and all(p.dtype == np.uint8 for p in first)
    assert len({float(p.std()) for p in first}) == 6  # six different pages, not one repeated


@pytest.mark.parametrize("rotation", [0, 90])
def test_the_8bit_gate_finds_the_lines_the_float_gate_finds(rotation):
    page = rotate_view(cv2.cvtColor(text_page(), cv2.COLOR_BGR2GRAY), rotation)
    float_gate, int8_gate = LineDetector(precision="float"), LineDetector(precision="int8")
    assert (float_gate.model.precision, int8_gate.model.precision) == ("float", "int8")
    assert float_gate.model.path == model_path()
    assert int8_gate.model.path != model_path() and int8_gate.model.path.is_file()
    found = {name: gate.scan(page).lines for name, gate in (("float", float_gate), ("int8", int8_gate))}
    assert len(found["int8"]) == len(found["float"]) >= 6
    assert {ln.axis for ln in found["int8"]} == {ln.axis for ln in found["float"]} == {"h" if rotation == 0 else "v"}
    centre = 1 if rotation == 0 else 0
    assert np.allclose(sorted(ln.center[centre] for ln in found["int8"]),
                       sorted(ln.center[centre] for ln in found["float"]), atol=4.0)


def test_the_8bit_gate_finds_no_line_in_a_texture():
    noise = np.random.default_rng(0).uniform(0, 255, (600, 800)).astype(np.uint8)
    texture = cv2.GaussianBlur(noise, (0, 0), 6)  # mottled stone or foliage: no letters
    assert LineDetector(precision="int8").scan(texture).lines == ()


def test_the_gate_runs_in_float_unless_set_otherwise(monkeypatch):
    from workers.orientation import textlines

    monkeypatch.delenv("SWEEPCAST_ORIENTATION_GATE_PRECISION", raising=False)
    assert textlines.get_line_detector().model.precision == "float"
    monkeypatch.setenv("SWEEPCAST_ORIENTATION_GATE_PRECISION", "int8")
    assert textlines.get_line_detector().model.precision == "int8"


def test_auto_keeps_the_float_model_on_a_cpu_without_vnni(monkeypatch):
    monkeypatch.setattr(quantize, "int8_fast", lambda: False)
    chosen = quantize.gate_model(model_path(), "auto", _to_input)
    assert chosen.precision == "float" and chosen.path == model_path() and "VNNI" in chosen.detail


def test_a_model_that_disagrees_with_the_float_one_is_refused_once_and_not_built_again(tmp_path, monkeypatch):
    monkeypatch.setenv("SWEEPCAST_MODEL_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(quantize, "agreement", lambda *a: 0.5)
    chosen = quantize.gate_model(model_path(), "int8", _to_input)
    assert chosen.precision == "float" and chosen.path == model_path() and "disagreed" in chosen.detail
    assert [p.suffix for p in tmp_path.glob("*.refused")] == [".refused"] and not list(tmp_path.glob("*.onnx"))

    def build_again(*args):
        raise AssertionError("a refused model was built again")

    monkeypatch.setattr(quantize, "quantize", build_again)
    assert quantize.gate_model(model_path(), "int8", _to_input).precision == "float"


def test_a_cache_that_cannot_be_written_keeps_the_float_model_and_says_why(tmp_path, monkeypatch):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the cache folder should be")
    monkeypatch.setenv("SWEEPCAST_MODEL_CACHE_DIR", str(blocker / "models"))
    chosen = quantize.gate_model(model_path(), "int8", _to_input)
    assert chosen.precision == "float" and "could not be built" in chosen.detail


def test_float_precision_is_the_float_model(tmp_path):
    assert quantize.gate_model(model_path(), "float", _to_input) == quantize.GateModel(
        Path(model_path()), "float", "float model (SWEEPCAST_ORIENTATION_GATE_PRECISION=int8: 8-bit, faster)")
