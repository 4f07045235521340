"""The benchmark's seam and pop measures (benchmarks/sweep/weighting.py, issue 22) on constructed known answers."""
import numpy as np
import pytest

from benchmarks.sweep.weighting import SEAM_TAU, pop_share, seam_measure


def _case(weights):
    """A 1 x 4 view over 2 cameras that see uniform colours 100 (camera 0) and 130 (camera 1) everywhere."""
    w = np.asarray(weights, np.float32)[None]  # (1, 4, 2)
    colours = np.empty((1, 4, 2, 3), np.float32)
    colours[:, :, 0] = 100.0
    colours[:, :, 1] = 130.0
    valid = np.ones((1, 4, 2), bool)
    depth = np.full((1, 4), 2.0, np.float32)
    mask = np.ones((1, 4), bool)
    return w, colours, valid, depth, mask


def test_a_weight_jump_where_the_camera_set_changes_is_a_seam_of_its_size():
    # pixels 0 -> 1: camera 1 enters with weight 0.5 (a jump: step 0.5 * 30 = 15 levels);
    # 1 -> 2: same set, weights move (no curve); 2 -> 3: camera 1 leaves from weight 0.01 (step 0.3)
    stats, emap = seam_measure(*_case([[1, 0], [0.5, 0.5], [0.99, 0.01], [1, 0]]))
    assert stats["curve_pairs"] == 2 and stats["seams"] == 1
    assert stats["max_step"] == pytest.approx(15.0)
    assert stats["mean_step"] == pytest.approx((15.0 + 0.3) / 2)
    assert stats["seams_per_10k_px"] == pytest.approx(1e4 / 4)
    assert emap[0, 0] == pytest.approx(15.0) and np.isnan(emap[0, 1]) and emap[0, 2] == pytest.approx(0.3, rel=1e-5)


def test_depth_edges_and_unscored_pixels_are_not_curves():
    w, colours, valid, depth, mask = _case([[1, 0], [0, 1], [1, 0], [0, 1]])
    depth[0, 1] = 3.0  # pairs 0-1 and 1-2 cross a depth edge
    mask[0, 3] = False  # pair 2-3 leaves the scored pixels
    stats, emap = seam_measure(w, colours, valid, depth, mask)
    assert stats["curve_pairs"] == 0 and stats["seams"] == 0 and np.isnan(emap).all()


def test_a_camera_seen_on_one_side_only_uses_that_sample():
    w, colours, valid, depth, mask = _case([[1, 0], [0, 1], [0, 1], [0, 1]])
    valid[0, 0, 1] = False  # camera 1 cannot see pixel 0's point: its colour there is not used
    colours[0, 0, 1] = 0.0
    stats, _ = seam_measure(w, colours, valid, depth, mask)
    assert stats["curve_pairs"] == 1 and stats["max_step"] == pytest.approx(30.0)


def test_pop_share_counts_the_pixels_changing_beyond_the_truth():
    h, w = 40, 40
    prev = np.full((h, w, 3), 100, np.uint8)
    cur = prev.copy()
    cur[:, :10] = 100 + 20  # a quarter of the frame pops by 20 levels; the truth stays still
    truth = np.full((h, w, 3), 50, np.uint8)
    mask = np.ones((h, w), bool)
    share = pop_share(prev, cur, truth, truth, mask)
    # the quarter, and the 2 columns beside it where the smoothed step, 20 Phi(-(j + 0.5) / 1.5), is above 2 levels
    assert share == pytest.approx(12 / 40)
    assert pop_share(prev, prev, truth, truth, mask) == 0.0
    moving_truth = truth.copy()
    moving_truth[:, :10] += 20  # the truth changes there too: nothing beyond it
    assert pop_share(prev, cur, truth, moving_truth, mask) == 0.0
    assert SEAM_TAU == 2.0  # the threshold the 12 columns above assume
