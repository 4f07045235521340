"""Quality measures against known answers."""
import cv2
import numpy as np
import pytest

from benchmarks.sweep.view_metrics import frame_jump, highfreq_ratio


def _img(seed=0):
    return np.random.default_rng(seed).integers(0, 256, size=(64, 80, 3), dtype=np.uint8)


def test_highfreq_ratio_detects_blur():
    a = cv2.resize(_img(), (160, 128), interpolation=cv2.INTER_NEAREST)
    assert highfreq_ratio(a, a) == pytest.approx(1.0)
    assert highfreq_ratio(cv2.GaussianBlur(a, (0, 0), 1.5), a) < 0.5


def test_frame_jump_is_mean_absolute_change():
    a = np.zeros((4, 4, 3), np.uint8)
    b = a.copy()
    b[..., 0] = 30  # one channel of three
    assert frame_jump(a, b) == pytest.approx(10.0)
