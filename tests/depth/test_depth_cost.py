"""The cost estimates of synchronous depth requests: known answers from the measured rates, and the sizes read
from the image headers the way the engine will read them."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from workers.depth.cost import filter_estimate, synthesis_estimate
from workers.depth.encoded import filter_work, synthesis_work
from workers.depth.methods import FilterOptions
from workers.depth.params import DepthFilterParams, SynthesizeParams


def png(array: np.ndarray) -> bytes:
    return cv2.imencode(".png", array)[1].tobytes()


def test_default_wmf_on_one_megapixel():
    est = filter_estimate(1_000_000, "wmf", FilterOptions())
    # 0.053 + 0.0048 * 9^2 + 0.0055 * (2 * 12 + 1) + 0.015 s per MP; 28 bytes per pixel
    assert est.cpu_seconds == pytest.approx(0.5943) and est.peak_bytes == 28_000_000


def test_costs_grow_with_the_taps_each_pixel_reads():
    base = FilterOptions()
    assert filter_estimate(10**6, "wmf", FilterOptions(guide_window=31)).cpu_seconds == pytest.approx(
        0.053 + 0.0048 * 961 + 0.0055 * 25 + 0.015)
    jbu = filter_estimate(10**6, "jbu", FilterOptions(jbu_radius=15)).cpu_seconds
    assert jbu == pytest.approx(0.091 + 0.0069 * 961)
    otsu = filter_estimate(10**6, "modified", FilterOptions(rule="otsu", window=31)).cpu_seconds
    assert otsu == pytest.approx(0.015 + 0.0016 * 31**3)  # ~48 s: the measured 48.9 s per MP
    assert filter_estimate(10**6, "modified", FilterOptions(window=31)).cpu_seconds == filter_estimate(
        10**6, "dilation", base).cpu_seconds == pytest.approx(0.015)


def test_synthesis_cost_per_view():
    est = synthesis_estimate([10**6, 10**6], 10**6, "rectified")
    assert est.cpu_seconds == pytest.approx(0.15 + 0.3) and est.peak_bytes == 42 * 10**6 + 68 * 10**6
    est = synthesis_estimate([10**6], 2 * 10**6, "general")
    assert est.cpu_seconds == pytest.approx(0.32 + 0.24) and est.peak_bytes == 332 * 10**6 + 29 * 10**6


def test_filter_work_reads_the_output_size_from_scale_texture_or_depth():
    depth = png(np.zeros((50, 100), np.uint8))
    est, what = filter_work(depth, DepthFilterParams(method="dilation", scale=2))
    assert what == "dilation on a 200x100 output" and est.peak_bytes == 3 * 200 * 100
    texture = png(np.zeros((100, 200, 3), np.uint8))
    assert filter_work(depth, DepthFilterParams(), texture)[1] == "wmf_dilation on a 200x100 output"
    assert filter_work(depth, DepthFilterParams(out_width=30, out_height=20))[1] == "dilation on a 30x20 output"
    assert filter_work(depth, DepthFilterParams())[1] == "dilation on a 100x50 output"


def test_inputs_the_engine_refuses_itself_have_no_estimate():
    depth = png(np.zeros((50, 100), np.uint8))
    assert filter_work(b"not an image", DepthFilterParams()) is None
    assert filter_work(depth, DepthFilterParams(scale=2), max_pixels=5000) is None  # output over the pixel limit
    assert filter_work(depth, DepthFilterParams(), max_pixels=100) is None
    params = SynthesizeParams(depth_units="disparity", positions=[0], target_position=1)
    assert synthesis_work([(b"", depth)], params) is None


def test_synthesis_work_takes_the_target_size_from_the_target_camera():
    texture = png(np.zeros((40, 60, 3), np.uint8))
    K = [[50.0, 0, 30], [0, 50.0, 20], [0, 0, 1]]
    params = SynthesizeParams(geometry="general", z_near=1, z_far=10, cameras=[{"K": K}],
                              target_camera={"K": K, "t": [0.1, 0, 0], "width": 120})
    est, what = synthesis_work([(texture, b"")], params)
    assert what == "synthesis of a 120x40 view from 1 view(s)"
    assert est == synthesis_estimate([60 * 40], 120 * 40, "general")
