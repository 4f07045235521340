import cv2
import numpy as np
import pytest

from workers.depth.errors import DepthInputError
from workers.depth.filters import (
    classify_foreground, dilation, modified_dilation, modified_dilation_morph, morphological_cleanup,
)
from workers.depth.methods import FilterOptions, apply_method
from workers.depth.upsample import upsample

BG, FG = 40, 200


def square(size=24, lo=8, hi=16, dtype=np.uint8, bg=BG, fg=FG):
    d = np.full((size, size), bg, dtype)
    d[lo:hi, lo:hi] = fg
    return d


def test_dilation_grows_the_square_by_the_window_radius():
    for window, grow in ((3, 1), (5, 2)):
        np.testing.assert_array_equal(dilation(square(), window), square(lo=8 - grow, hi=16 + grow))


def test_modified_dilation_leaves_a_sharp_edge_in_place():
    np.testing.assert_array_equal(modified_dilation(square(), 3), square())


def test_modified_dilation_restores_the_foreground_of_a_blurred_edge():
    # decoded depth: a 2x-downsampled square upsampled bilinearly has ramps at its edges
    low = cv2.resize(square(), (12, 12), interpolation=cv2.INTER_AREA)
    up = upsample(low, scale=2, mode="bilinear")
    out = modified_dilation(up, 3)
    fg = classify_foreground(up, 3)
    background = ~fg
    # background pixels never change (so never take foreground values) ...
    np.testing.assert_array_equal(out[background], up[background])
    # ... foreground pixels take the window maximum (eq. 1) ...
    np.testing.assert_array_equal(out[fg], dilation(up, 3)[fg])
    # ... and the foreground never grows past the original square, unlike plain dilation
    outside = square() == BG
    assert (out[outside] < FG).all()
    assert (out[outside] >= (BG + FG) // 2).sum() < (dilation(up, 3)[outside] >= (BG + FG) // 2).sum()


def test_modified_dilation_never_changes_background_away_from_an_edge():
    rng = np.random.default_rng(1)
    noisy = square().astype(np.int16) + rng.integers(-3, 4, (24, 24))
    noisy = noisy.astype(np.uint8)
    out = modified_dilation(noisy, 3, min_contrast=16)
    far = cv2.erode((square() == BG).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0  # >= 2 px from the edge
    np.testing.assert_array_equal(out[far], noisy[far])
    # next to the edge the foreground is lifted to its window maximum
    fg = square() == FG
    assert (out[fg] >= noisy[fg]).all()


def test_cleanup_removes_isolated_misclassified_pixels():
    clean = square()
    specks = clean.copy()
    specks[10, 10] = BG  # a foreground pixel left at background level
    specks[12, 14] = BG
    specks[2, 3] = FG  # a background pixel raised to foreground
    specks[20, 18] = FG
    np.testing.assert_array_equal(morphological_cleanup(specks, 3, "close-open"), clean)
    closed = morphological_cleanup(specks, 3, "close")  # the paper's order fills the dark specks
    assert closed[10, 10] == FG and closed[12, 14] == FG
    opened = morphological_cleanup(specks, 3, "open")
    assert opened[2, 3] == BG and opened[20, 18] == BG


def test_full_method_is_modified_then_cleanup():
    up = upsample(cv2.resize(square(), (12, 12), interpolation=cv2.INTER_AREA), scale=2, mode="bilinear")
    expected = morphological_cleanup(modified_dilation(up, 5), 3, "close")
    np.testing.assert_array_equal(modified_dilation_morph(up, 5, morph_window=3), expected)


def test_otsu_rule_agrees_with_midrange_on_two_level_windows():
    d = square()
    np.testing.assert_array_equal(classify_foreground(d, 3, "otsu"), classify_foreground(d, 3, "midrange"))
    # on a three-level ramp Otsu puts the middle level with the nearer one when it is closer to it
    ramp = np.array([[10, 10, 90, 100, 100]], np.uint8).repeat(3, 0)
    assert classify_foreground(ramp, 5, "otsu")[1, 2]
    assert not classify_foreground(ramp, 5, "otsu")[1, 0]


def test_sixteen_bit_matches_eight_bit_scaled():
    low = cv2.resize(square(), (12, 12), interpolation=cv2.INTER_AREA)
    up8 = upsample(low, scale=2, mode="bilinear")
    up16 = up8.astype(np.uint16) * 257
    a = modified_dilation_morph(up8, 3)
    b = modified_dilation_morph(up16, 3)
    np.testing.assert_array_equal(b, a.astype(np.uint16) * 257)


def test_opposite_convention_dilates_the_small_levels():
    d = square()
    opts = FilterOptions(larger_is_nearer=False)
    flipped = (255 - d).astype(np.uint8)
    np.testing.assert_array_equal(apply_method(flipped, "dilation", options=opts), 255 - dilation(d, 3))


def test_bad_parameters():
    with pytest.raises(DepthInputError, match="window must be an odd integer"):
        dilation(square(), 4)
    with pytest.raises(DepthInputError, match="unknown classification rule"):
        modified_dilation(square(), 3, rule="kmeans")
    with pytest.raises(DepthInputError, match="unknown morphology order"):
        morphological_cleanup(square(), 3, "erode")
