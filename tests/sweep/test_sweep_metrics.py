"""Quality measures against known answers."""
import cv2
import numpy as np
import pytest

from workers.sweep.metrics import frame_jump, highfreq_ratio, psnr, ssim


def _img(seed=0):
    return np.random.default_rng(seed).integers(0, 256, size=(64, 80, 3), dtype=np.uint8)


def test_psnr_known_values():
    a = np.full((10, 10, 3), 100, np.uint8)
    assert psnr(a, a) == float("inf")
    assert psnr(a, a + 1) == pytest.approx(10 * np.log10(255**2))
    mask = np.zeros((10, 10), bool)
    mask[:5] = True
    b = a.copy()
    b[5:] = 0  # outside the mask
    assert psnr(a, b, mask) == float("inf")


def test_ssim_identity_noise_and_constant_shift():
    a = _img()
    assert ssim(a, a) == pytest.approx(1.0)
    assert ssim(a, 255 - a) < -0.9  # inverted structure
    smooth = cv2.GaussianBlur(a, (0, 0), 3)
    noisy = np.clip(smooth.astype(int) + np.random.default_rng(1).normal(0, 40, a.shape), 0, 255).astype(np.uint8)
    assert ssim(smooth, noisy) < 0.3  # noise far stronger than the structure
    assert 0.9 < ssim(smooth, np.clip(smooth.astype(int) + 5, 0, 255).astype(np.uint8)) < 1.0


def test_highfreq_ratio_detects_blur():
    a = cv2.resize(_img(), (160, 128), interpolation=cv2.INTER_NEAREST)
    assert highfreq_ratio(a, a) == pytest.approx(1.0)
    assert highfreq_ratio(cv2.GaussianBlur(a, (0, 0), 1.5), a) < 0.5


def test_frame_jump_is_mean_absolute_change():
    a = np.zeros((4, 4, 3), np.uint8)
    b = a.copy()
    b[..., 0] = 30  # one channel of three
    assert frame_jump(a, b) == pytest.approx(10.0)
