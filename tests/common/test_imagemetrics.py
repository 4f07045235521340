"""PSNR and SSIM, the one definition every engine and benchmark uses, against known answers."""
import cv2
import numpy as np
import pytest

from workers.common.imagemetrics import luma, psnr, ssim, ssim_map


def _img(seed=0, shape=(64, 80, 3)):
    return np.random.default_rng(seed).integers(0, 256, size=shape, dtype=np.uint8)


def test_psnr_known_values():
    a = np.zeros((4, 4, 3), np.uint8)
    assert psnr(a, a) == float("inf")
    assert psnr(a, a + 10) == pytest.approx(10 * np.log10(255**2 / 100))  # MSE 100
    mask = np.zeros((4, 4), bool)
    mask[0, 0] = True
    c = a.copy()
    c[0, 0] = 5
    c[1, 1] = 200  # outside the mask
    assert psnr(a, c, mask) == pytest.approx(10 * np.log10(255**2 / 25))


def test_psnr_averages_the_channels_of_each_masked_pixel():
    a = np.zeros((2, 2, 3), np.uint8)
    b = a.copy()
    b[0, 0, 0] = 30  # one channel of one pixel: squared error 900 over 3 channels
    mask = np.array([[True, False], [False, False]])
    assert psnr(a, b, mask) == pytest.approx(10 * np.log10(255**2 / 300))
    assert psnr(a, b) == pytest.approx(10 * np.log10(255**2 / 75))
    assert np.isnan(psnr(a, b, np.zeros((2, 2), bool)))


def test_shapes_must_match():
    with pytest.raises(ValueError, match="differ in shape"):
        psnr(np.zeros((4, 4)), np.zeros((4, 5)))
    with pytest.raises(ValueError, match="differ in shape"):
        ssim(np.zeros((4, 4)), np.zeros((5, 4)))


def test_ssim_identity_noise_inversion_and_constant_shift():
    a = _img()
    assert ssim(a, a) == pytest.approx(1.0)
    assert ssim(a, 255 - a) < -0.9  # inverted structure
    smooth = cv2.GaussianBlur(a, (0, 0), 3)
    noisy = np.clip(smooth.astype(int) + np.random.default_rng(1).normal(0, 40, a.shape), 0, 255).astype(np.uint8)
    assert ssim(smooth, noisy) < 0.3  # noise far stronger than the structure
    # a constant offset keeps structure and contrast: SSIM stays high, PSNR does not
    assert 0.9 < ssim(smooth, np.clip(smooth.astype(int) + 5, 0, 255).astype(np.uint8)) < 1.0


def test_ssim_of_flat_images_is_the_luminance_term():
    a = np.full((16, 16), 100, np.uint8)
    b = np.full((16, 16), 110, np.uint8)
    c1 = (0.01 * 255) ** 2
    assert ssim(a, b) == pytest.approx((2 * 100 * 110 + c1) / (100**2 + 110**2 + c1), rel=1e-9)


def test_ssim_mask_averages_the_map_where_true():
    a, b = _img(0), _img(1)
    mask = np.zeros(a.shape[:2], bool)
    mask[10:30, 5:50] = True
    assert ssim(a, b, mask) == pytest.approx(ssim_map(a, b)[mask].mean())
    assert np.isnan(ssim(a, b, np.zeros_like(mask)))


def test_luma_uses_bt601_weights_on_bgr():
    img = np.zeros((1, 3, 3), np.uint8)
    img[0, 0, 0], img[0, 1, 1], img[0, 2, 2] = 100, 100, 100  # pure blue, green, red
    np.testing.assert_allclose(luma(img)[0], [11.4, 58.7, 29.9])


def test_ssim_map_is_scikit_images():
    metrics = pytest.importorskip("skimage.metrics")
    smooth = cv2.GaussianBlur(_img(2, (48, 56, 3)), (0, 0), 2)
    other = np.clip(smooth.astype(int) + np.random.default_rng(3).normal(0, 12, smooth.shape), 0, 255)
    _, reference = metrics.structural_similarity(
        luma(smooth), luma(other), data_range=255, gaussian_weights=True, sigma=1.5,
        use_sample_covariance=False, full=True)
    np.testing.assert_allclose(ssim_map(smooth, other), reference, atol=1e-9)
