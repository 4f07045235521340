import numpy as np
import pytest

from workers.depth import METHODS, DepthInputError, FilterOptions, apply_method, postprocess
from workers.depth.filters import modified_dilation_morph
from workers.depth.upsample import upsample


def test_registry_has_the_paper_methods_and_the_edge_aware_one():
    assert {"none", "dilation", "modified", "modified_morph", "wmf"} <= set(METHODS)


def test_postprocess_is_upsampling_then_the_method():
    rng = np.random.default_rng(0)
    low = rng.integers(0, 256, (9, 11), dtype=np.uint8)
    out = postprocess(low, "modified_morph", scale=2, upsampler="bilinear")
    np.testing.assert_array_equal(out, modified_dilation_morph(upsample(low, scale=2, mode="bilinear"), 3))
    assert postprocess(low, "none", size=(30, 20)).shape == (20, 30)


def test_guide_sets_the_output_size():
    low = np.zeros((6, 8), np.uint8)
    guide = np.zeros((12, 16, 3), np.uint8)
    assert postprocess(low, "wmf", guide=guide).shape == (12, 16)


def test_unknown_method():
    with pytest.raises(DepthInputError, match="unknown method 'median'; expected one of none, dilation"):
        apply_method(np.zeros((4, 4), np.uint8), "median")


def test_guided_method_needs_a_matching_texture():
    depth = np.zeros((8, 8), np.uint8)
    with pytest.raises(DepthInputError, match="needs a texture"):
        apply_method(depth, "wmf")
    with pytest.raises(DepthInputError, match="texture is 4x8 but the depth map is 8x8"):
        apply_method(depth, "dilation", guide=np.zeros((8, 4, 3), np.uint8))


def test_bit_depth_must_match_the_options():
    with pytest.raises(DepthInputError, match="bit depth 8 expects uint8"):
        apply_method(np.zeros((4, 4), np.uint16), "dilation")
    out = apply_method(np.full((4, 4), 1000, np.uint16), "dilation", options=FilterOptions(bits=10))
    assert out.dtype == np.uint16 and (out == 1000).all()


def test_factor_zero_is_refused():
    with pytest.raises(DepthInputError, match="scale factor must be a positive number, got 0"):
        postprocess(np.zeros((4, 4), np.uint8), "dilation", scale=0)


def test_jbu_reads_the_low_resolution_map_itself():
    from workers.depth.edge_aware import joint_bilateral_upsample

    rng = np.random.default_rng(1)
    low = rng.integers(0, 256, (6, 8), dtype=np.uint8)
    guide = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
    expected = joint_bilateral_upsample(low, guide, 2, 1.0, 12.0)
    for up in ("nearest", "bilinear"):
        np.testing.assert_array_equal(postprocess(low, "jbu", upsampler=up, guide=guide), expected)
    with pytest.raises(DepthInputError, match="needs a texture"):
        postprocess(low, "jbu", scale=2)


def test_wmf_dilation_is_the_weighted_mode_filter_then_dilation():
    from workers.depth.edge_aware import weighted_mode_filter
    from workers.depth.filters import dilation

    rng = np.random.default_rng(2)
    depth = rng.integers(0, 256, (12, 16), dtype=np.uint8)
    guide = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
    out = apply_method(depth, "wmf_dilation", guide, FilterOptions(window=3))
    np.testing.assert_array_equal(out, dilation(weighted_mode_filter(depth, guide, 9, sigma_color=40.0), 3))


def test_auto_picks_the_recommended_method():
    from workers.depth.methods import recommended_method
    from workers.depth.params import DepthFilterParams

    p = DepthFilterParams()
    assert p.method == "auto"
    assert p.method_for(True) == recommended_method(True) == "wmf_dilation"
    assert p.method_for(False) == recommended_method(False) == "dilation"
    assert DepthFilterParams(method="modified").method_for(True) == "modified"
