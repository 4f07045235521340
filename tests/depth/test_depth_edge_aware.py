import numpy as np
import pytest

import cv2

from workers.depth.edge_aware import joint_bilateral_upsample, weighted_mode_filter
from workers.depth.errors import DepthInputError
from workers.depth.upsample import upsample


def step_scene(edge=13, size=24):
    """True depth and texture with a vertical edge at column ``edge`` (odd, so 2x decimation misses it)."""
    depth = np.full((size, size), 50, np.uint8)
    depth[:, edge:] = 180
    rng = np.random.default_rng(3)
    texture = np.where(depth[..., None] == 180, 200, 30).astype(np.int16) + rng.integers(-4, 5, (size, size, 3))
    return depth, texture.clip(0, 255).astype(np.uint8)


def test_wmf_moves_a_blocky_edge_onto_the_texture_edge():
    truth, texture = step_scene()
    blocky = upsample(truth[::2, ::2], scale=2)  # decoded at half resolution: the edge is off by one
    assert (blocky != truth).any()
    out = weighted_mode_filter(blocky, texture, window=5, sigma_color=10.0)
    np.testing.assert_array_equal(out, truth)


def test_wmf_outputs_only_levels_present_nearby():
    rng = np.random.default_rng(0)
    depth = rng.choice(np.array([10, 90, 250], np.uint8), (16, 16))
    texture = rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)
    out = weighted_mode_filter(depth, texture, window=5)
    assert set(np.unique(out)) <= {10, 90, 250}


def test_wmf_sixteen_bit():
    truth, texture = step_scene()
    blocky = upsample(truth[::2, ::2], scale=2).astype(np.uint16) * 257
    out = weighted_mode_filter(blocky, texture, window=5, sigma_color=10.0)
    np.testing.assert_array_equal(out, truth.astype(np.uint16) * 257)


def test_wmf_bad_input():
    depth, texture = step_scene()
    with pytest.raises(DepthInputError, match="texture is 12x24 but the depth map is 24x24"):
        weighted_mode_filter(depth, texture[:, :12])
    with pytest.raises(DepthInputError, match="needs a texture"):
        weighted_mode_filter(depth, None)
    with pytest.raises(DepthInputError, match="odd integer"):
        weighted_mode_filter(depth, texture, window=4)


def area_low(depth, factor=2):
    h, w = depth.shape
    return cv2.resize(depth, (w // factor, h // factor), interpolation=cv2.INTER_AREA)


@pytest.mark.parametrize("edge", [13, 14])
def test_jbu_puts_the_edge_on_the_texture_edge(edge):
    # area downsampling blends the two depths where the edge cuts a 2x2 block (odd edge); the guide
    # there is mixed too, so the colour term gives that sample no weight and the edge comes back exact
    truth, texture = step_scene(edge)
    out = joint_bilateral_upsample(area_low(truth), texture, radius=2, sigma_color=10.0)
    np.testing.assert_array_equal(out, truth)


def test_jbu_with_a_flat_guide_is_a_gaussian_weighted_mean():
    low = np.array([[0, 0, 0], [0, 90, 0], [0, 0, 0]], np.uint8)
    guide = np.zeros((3, 3, 3), np.uint8)  # factor 1, flat guide: a normalised Gaussian blur
    out = joint_bilateral_upsample(low, guide, radius=1, sigma_spatial=1.0)
    g = np.exp(-0.5)  # weight of an edge neighbour, exp(-1) of a diagonal one
    centre = 90 / (1 + 4 * g + 4 * np.exp(-1.0))
    corner = 90 * np.exp(-1.0) / (1 + 2 * g + np.exp(-1.0))
    assert out[1, 1] == round(centre) and out[0, 0] == round(corner)


def test_jbu_keeps_sixteen_bits_and_a_constant_map():
    flat = np.full((6, 8), 40000, np.uint16)
    texture = np.random.default_rng(0).integers(0, 256, (12, 16, 3), dtype=np.uint8)
    out = joint_bilateral_upsample(flat, texture)
    assert out.dtype == np.uint16 and (out == 40000).all()


def test_jbu_bad_input():
    with pytest.raises(DepthInputError, match="radius"):
        joint_bilateral_upsample(np.zeros((4, 4), np.uint8), np.zeros((8, 8, 3), np.uint8), radius=0)
    with pytest.raises(DepthInputError, match="sigma_color"):
        joint_bilateral_upsample(np.zeros((4, 4), np.uint8), np.zeros((8, 8, 3), np.uint8), sigma_color=0)
