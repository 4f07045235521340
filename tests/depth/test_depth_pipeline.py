import cv2
import numpy as np
import pytest

from workers.depth.errors import DepthInputError
from workers.depth.methods import FilterOptions, postprocess
from workers.depth.pipeline import FramePipeline


def decoded_frame(h=30, w=40, dtype=np.uint8, seed=0):
    rng = np.random.default_rng(seed)
    d = np.full((h, w), 50, np.uint8)
    for _ in range(6):
        cv2.circle(d, (int(rng.integers(0, w)), int(rng.integers(0, h))), int(rng.integers(3, 10)),
                   int(rng.integers(80, 250)), -1)
    ok, buf = cv2.imencode(".jpg", d, [cv2.IMWRITE_JPEG_QUALITY, 40])
    d = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
    return d if dtype == np.uint8 else d.astype(np.uint16) * 64


@pytest.mark.parametrize("method", ["none", "dilation", "modified", "modified_morph"])
@pytest.mark.parametrize("options", [
    FilterOptions(),
    FilterOptions(window=5, min_contrast=12, morph_order="close-open"),
    FilterOptions(larger_is_nearer=False, morph_order="open"),
    FilterOptions(rule="otsu"),
])
@pytest.mark.parametrize("upsampler", ["nearest", "bilinear"])
def test_pipeline_matches_postprocess(method, options, upsampler):
    low = decoded_frame()
    pipe = FramePipeline(low.shape, (80, 60), method, upsampler, options)
    for seed in (0, 1):  # buffers are reused between frames
        low = decoded_frame(seed=seed)
        expected = postprocess(low, method, size=(80, 60), upsampler=upsampler, options=options)
        np.testing.assert_array_equal(pipe(low), expected)
        np.testing.assert_array_equal(pipe.upsampled, postprocess(low, "none", size=(80, 60), upsampler=upsampler))


def test_pipeline_sixteen_bit_and_guided():
    low = decoded_frame(dtype=np.uint16)
    opts = FilterOptions(bits=14)
    pipe = FramePipeline(low.shape, (60, 45), "modified_morph", options=opts)
    np.testing.assert_array_equal(pipe(low), postprocess(low, "modified_morph", size=(60, 45), options=opts))
    guide = np.zeros((45, 60, 3), np.uint8)
    wmf = FramePipeline(low.shape, (60, 45), "wmf", options=opts)
    np.testing.assert_array_equal(wmf(low, guide), postprocess(low, "wmf", guide=guide, options=opts))


def test_pipeline_bad_input():
    pipe = FramePipeline((30, 40), (80, 60), "dilation")
    with pytest.raises(DepthInputError, match="frame is 41x30, expected 40x30"):
        pipe(np.zeros((30, 41), np.uint8))
    with pytest.raises(DepthInputError, match="bit depth 8 expects uint8"):
        pipe(np.zeros((30, 40), np.uint16))
    with pytest.raises(DepthInputError, match="unknown method"):
        FramePipeline((30, 40), (80, 60), "sharpen")
