import numpy as np
import pytest

from workers.depth import metrics


def test_psnr_known_values():
    a = np.zeros((4, 4, 3), np.uint8)
    b = a.copy()
    assert metrics.psnr(a, b) == float("inf")
    b[...] = 10  # MSE 100
    assert metrics.psnr(a, b) == pytest.approx(10 * np.log10(255**2 / 100))
    mask = np.zeros((4, 4), bool)
    mask[0, 0] = True
    c = a.copy()
    c[0, 0] = 5
    c[1, 1] = 200
    assert metrics.psnr(a, c, mask) == pytest.approx(10 * np.log10(255**2 / 25))


def test_ssim_is_one_for_identical_and_drops_with_noise():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (32, 32, 3), dtype=np.uint8)
    assert metrics.ssim(img, img) == pytest.approx(1.0)
    noisy = np.clip(img.astype(int) + rng.integers(-40, 41, img.shape), 0, 255).astype(np.uint8)
    noisier = np.clip(img.astype(int) + rng.integers(-120, 121, img.shape), 0, 255).astype(np.uint8)
    assert 0 < metrics.ssim(img, noisier) < metrics.ssim(img, noisy) < 1
    # a constant offset keeps structure and contrast: SSIM stays high, PSNR does not
    shifted = np.clip(img.astype(int) + 20, 0, 255).astype(np.uint8)
    assert metrics.ssim(img, shifted) > metrics.ssim(img, noisy)


def test_ssim_of_flat_images_with_different_means():
    a = np.full((16, 16), 100, np.uint8)
    b = np.full((16, 16), 110, np.uint8)
    c1 = (0.01 * 255) ** 2
    expected = (2 * 100 * 110 + c1) / (100**2 + 110**2 + c1)
    assert metrics.ssim(a, b) == pytest.approx(expected, rel=1e-6)


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
