import numpy as np
import pytest

from workers.depth.edge_aware import weighted_mode_filter
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
