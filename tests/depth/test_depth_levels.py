import numpy as np
import pytest

from workers.depth.errors import DepthInputError
from workers.depth.levels import (
    check_levels, depth_to_levels, disparity_to_levels, flip, levels_to_depth, levels_to_disparity,
)


def test_extreme_levels_are_the_clipping_planes():
    z = levels_to_depth(np.array([[0, 255]], np.uint8), z_near=2.0, z_far=10.0)
    np.testing.assert_allclose(z, [[10.0, 2.0]], rtol=1e-6)


def test_inverse_depth_is_linear_in_the_level():
    # the middle level is the harmonic mean of the planes, not the arithmetic one
    z = levels_to_depth(np.array([[32768]], np.uint16), 1.0, 3.0, bits=16)
    expected = 1.0 / (32768 / 65535 * (1.0 - 1 / 3) + 1 / 3)
    assert z[0, 0] == pytest.approx(expected, rel=1e-6)


def test_round_trip_8_and_16_bit():
    for bits, dtype in ((8, np.uint8), (10, np.uint16), (16, np.uint16)):
        levels = np.arange(0, 2**bits, max(1, 2**bits // 97), dtype=dtype)[None, :]
        back = depth_to_levels(levels_to_depth(levels, 0.5, 20.0, bits), 0.5, 20.0, bits)
        np.testing.assert_array_equal(back, levels)


def test_opposite_convention_reverses_the_axis():
    levels = np.array([[0, 100, 255]], np.uint8)
    a = levels_to_depth(levels, 1.0, 5.0, larger_is_nearer=False)
    b = levels_to_depth(flip(levels, 8), 1.0, 5.0)
    np.testing.assert_allclose(a, b)
    assert a[0, 0] == pytest.approx(1.0)  # level 0 is nearest in the opposite convention


def test_disparity_is_focal_baseline_over_depth():
    levels = np.array([[0, 128, 255]], np.uint8)
    d = levels_to_disparity(levels, 2.0, 8.0, focal_baseline=100.0)
    np.testing.assert_allclose(d, 100.0 / levels_to_depth(levels, 2.0, 8.0), rtol=1e-6)
    np.testing.assert_array_equal(disparity_to_levels(d, 2.0, 8.0, 100.0), levels)


def test_infinite_far_plane():
    z = levels_to_depth(np.array([[0, 255]], np.uint8), 1.0, float("inf"))
    assert np.isinf(z[0, 0]) and z[0, 1] == pytest.approx(1.0)


@pytest.mark.parametrize("near,far", [(0.0, 1.0), (2.0, 1.0), (-1.0, 3.0)])
def test_bad_planes(near, far):
    with pytest.raises(DepthInputError, match="z_near"):
        levels_to_depth(np.zeros((2, 2), np.uint8), near, far)


def test_check_levels_rejects_wrong_bit_depth():
    with pytest.raises(DepthInputError, match="bit depth 8 expects uint8"):
        check_levels(np.zeros((4, 4), np.uint16), 8)
    with pytest.raises(DepthInputError, match="above the 10-bit maximum 1023"):
        check_levels(np.full((4, 4), 1024, np.uint16), 10)
    with pytest.raises(DepthInputError, match="bit depth must be"):
        check_levels(np.zeros((4, 4), np.uint8), 7)
    with pytest.raises(DepthInputError, match="single-channel"):
        check_levels(np.zeros((4, 4, 3), np.uint8), 8)
