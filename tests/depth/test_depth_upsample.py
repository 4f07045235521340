import numpy as np
import pytest

from workers.depth.errors import DepthInputError
from workers.depth.upsample import target_size, upsample


def test_nearest_integer_factor_replicates_blocks():
    low = np.arange(12, dtype=np.uint8).reshape(3, 4)
    np.testing.assert_array_equal(upsample(low, scale=2), np.kron(low, np.ones((2, 2), np.uint8)))
    np.testing.assert_array_equal(upsample(low, scale=3), np.kron(low, np.ones((3, 3), np.uint8)))


def test_bilinear_keeps_constant_and_interpolates_a_ramp():
    flat = np.full((5, 5), 77, np.uint16)
    assert (upsample(flat, scale=2, mode="bilinear") == 77).all()
    ramp = np.array([[0, 100]], np.uint8).repeat(2, 0)
    up = upsample(ramp, scale=2, mode="bilinear")
    # pixel centres of the output sit at 1/4 and 3/4 between input samples
    np.testing.assert_array_equal(up[0], [0, 25, 75, 100])


def test_arbitrary_factor_and_explicit_size():
    low = np.zeros((10, 20), np.uint8)
    assert upsample(low, scale=1.5).shape == (15, 30)
    assert upsample(low, size=(33, 17), mode="bilinear").shape == (17, 33)
    assert target_size((10, 20)) == (20, 10)


@pytest.mark.parametrize("scale", [0, -2, float("nan"), float("inf")])
def test_bad_factor(scale):
    with pytest.raises(DepthInputError, match="scale factor must be a positive number"):
        upsample(np.zeros((4, 4), np.uint8), scale=scale)


def test_bad_size_and_mode():
    with pytest.raises(DepthInputError, match="either a scale factor or a target size"):
        target_size((4, 4), 2, (8, 8))
    with pytest.raises(DepthInputError, match="two positive integers"):
        target_size((4, 4), size=(0, 8))
    with pytest.raises(DepthInputError, match="unknown upsampler 'cubic'"):
        upsample(np.zeros((4, 4), np.uint8), scale=2, mode="cubic")
