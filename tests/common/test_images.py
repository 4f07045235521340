"""The one checked image decoder (workers/common/images.py) and the engines that decode through it."""
from __future__ import annotations

import struct

import cv2
import numpy as np
import pytest

from tests.common.hostile import jpeg_declaring, png_bomb
from workers.common import images
from workers.common.jobctx import JobInputError


def encoded(ext: str, image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(ext, image)
    assert ok
    return buf.tobytes()


@pytest.mark.parametrize("ext", [".jpg", ".png", ".webp", ".bmp", ".tiff", ".ppm", ".pgm"])
def test_header_size_matches_the_decoded_size(ext):
    image = np.zeros((30, 40, 3), np.uint8) if ext != ".pgm" else np.zeros((30, 40), np.uint8)
    data = encoded(ext, image)
    size = images.read_image_size(data)
    assert (size.width, size.height) == (40, 30)
    assert images.decode_image(data, cv2.IMREAD_UNCHANGED).shape[:2] == (30, 40)


def test_pnm_header_with_comments_and_bmp_top_down_rows():
    assert images.read_image_size(b"P5\n# made by hand\n7 # width\n5\n255\n" + bytes(35)).width == 7
    header = (b"BM" + struct.pack("<IHHI", 14 + 40 + 144, 0, 0, 54)
              + struct.pack("<IiiHHIIiiII", 40, 9, -4, 1, 32, 0, 144, 0, 0, 0, 0))  # height < 0: rows top-down
    assert images.read_image_size(header + bytes(144)).height == 4


def test_a_format_outside_the_supported_ones_is_refused_before_decoding():
    gif = cv2.imencode(".gif", np.zeros((4, 4, 3), np.uint8))[1].tobytes() if cv2.haveImageWriter(".gif") else \
        b"GIF89a\x04\x00\x04\x00\x80\x00\x00\x00\x00\x00\xff\xff\xff!\xf9\x04\x00\x00\x00\x00\x00," \
        b"\x00\x00\x00\x00\x04\x00\x04\x00\x00\x02\x04\x84\x8f\x07\x05\x00;"
    with pytest.raises(images.UnsupportedImage, match="GIF images are not supported"):
        images.decode_image(gif, cv2.IMREAD_COLOR)


def test_bombs_are_refused_from_the_header_before_decoding(monkeypatch):
    decoded = []
    monkeypatch.setattr(images.cv2, "imdecode", lambda *a: decoded.append(a))
    with pytest.raises(images.TooManyPixels, match="65000x65000"):
        images.decode_image(jpeg_declaring(65000, 65000), cv2.IMREAD_COLOR, 64_000_000)
    with pytest.raises(images.TooManyPixels, match="7900x7900"):
        images.decode_image(png_bomb(7900, 7900), cv2.IMREAD_UNCHANGED, 50_000_000)
    assert decoded == []


def test_the_limit_comes_from_the_environment_when_not_given(monkeypatch):
    data = encoded(".png", np.zeros((10, 10), np.uint8))
    monkeypatch.setenv(images.MAX_PIXELS_ENV, "99")
    with pytest.raises(images.TooManyPixels, match="the limit is 99 pixels"):
        images.decode_image(data, cv2.IMREAD_UNCHANGED)
    monkeypatch.setenv(images.MAX_PIXELS_ENV, "100")
    assert images.decode_image(data, cv2.IMREAD_UNCHANGED).shape == (10, 10)


@pytest.mark.parametrize("data, error", [
    (b"", images.EmptyImage),
    (b"hello world", images.NotAnImage),
    (b"\xff\xd8\xff\xe0\x00\x10JFIF", images.UnreadableImage),  # ends before a frame header
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x00\x00\x00\x00\x05", images.UnreadableImage),  # 0 wide
])
def test_what_users_get_wrong_is_an_input_error_not_a_cv2_error(data, error):
    with pytest.raises(error) as caught:
        images.decode_image(data, cv2.IMREAD_COLOR)
    assert isinstance(caught.value, (ValueError, JobInputError))


def test_damaged_pixel_data_is_an_input_error():
    data = encoded(".png", np.random.default_rng(0).integers(0, 255, (64, 64), np.uint8))
    broken = data[:60] + b"\x00" * 200 + data[260:]
    with pytest.raises(images.UnreadableImage):
        images.decode_image(broken, cv2.IMREAD_UNCHANGED)


def test_depth_engine_decodes_through_the_checked_decoder():
    from workers.depth import io

    with pytest.raises(images.EmptyImage, match="depth map: the file is empty") as caught:
        io.decode_depth(b"")
    assert caught.value.code == "empty_file"
    with pytest.raises(images.TooManyPixels, match="texture: .*65000x65000") as caught:
        io.decode_texture(jpeg_declaring(65000, 65000), 1_000_000)
    assert caught.value.code == "too_many_pixels"


def test_depth_output_is_checked_before_it_is_allocated():
    from workers.depth.errors import DepthInputError
    from workers.depth.encoded import filter_depth_bytes

    tiny = encoded(".png", np.full((8, 8), 9, np.uint8))
    with pytest.raises(DepthInputError, match="16384x16384") as caught:
        filter_depth_bytes(tiny, {"out_width": 16384, "out_height": 16384}, max_pixels=64_000_000)
    assert caught.value.code == "output_too_large"
    assert len(filter_depth_bytes(tiny, {"scale": 2}, max_pixels=256)) > 0  # 16 x 16 = the limit


def test_drone_stills_over_the_limit_are_skipped_with_a_reason(tmp_path, monkeypatch):
    from workers.drone.frames import open_media

    monkeypatch.setenv(images.MAX_PIXELS_ENV, "10000")
    (tmp_path / "001.png").write_bytes(encoded(".png", np.zeros((50, 50, 3), np.uint8)))
    (tmp_path / "002.png").write_bytes(png_bomb(7900, 7900))
    (tmp_path / "003.png").write_bytes(b"")
    source = open_media(tmp_path)
    assert [name for _, _, name, _ in source] == ["001.png"]
    assert any("002.png" in e and "7900x7900" in e for e in source.errors)
    assert any("003.png" in e and "empty" in e for e in source.errors)


def test_encode_png_is_lossless_for_8_and_16_bit_and_refuses_floats():
    from workers.common.images import encode_png

    rng = np.random.default_rng(0)
    for img in (rng.integers(0, 256, (5, 7, 3), np.uint8), rng.integers(0, 65536, (5, 7), np.uint16)):
        data = encode_png(img)
        assert data[:8] == b"\x89PNG\r\n\x1a\n"
        np.testing.assert_array_equal(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED), img)
    for bad in (np.zeros((4, 4, 7), np.uint8), np.zeros((4, 4), np.float64)):
        with pytest.raises(ValueError, match="as PNG"):
            encode_png(bad)
