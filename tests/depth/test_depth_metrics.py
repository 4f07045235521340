import numpy as np
import pytest

from workers.depth import metrics


def test_depth_errors_and_edge_band():
    truth = np.zeros((10, 10), np.float32)
    truth[:, 5:] = 10.0
    est = truth.copy()
    est[:, 4] = 10.0  # foreground one pixel too wide
    valid = np.ones_like(truth, bool)
    valid[0] = False
    e = metrics.depth_errors(est, truth, valid, bad_threshold=1.0)
    assert e["pixels"] == 90
    assert e["mae"] == pytest.approx(9 * 10 / 90)
    assert e["bad_rate"] == pytest.approx(0.1)
    band = metrics.edge_band(truth, jump=2.0, radius=1)
    np.testing.assert_array_equal(np.nonzero(band[5])[0], [3, 4, 5, 6])
    inner = metrics.depth_errors(est, truth, valid, 1.0, band)
    assert inner["bad_rate"] == pytest.approx(0.25)
