"""Reading photos: formats and sizes from headers, reduced decoding of stored pixels, and every bad input."""
from __future__ import annotations

import struct

import cv2
import numpy as np
import pytest

from harness.photos import asymmetric_image
from tests.orientation.builders import encode, insert_app1, jpeg, rich_exif
from workers.common import images
from workers.common.errors import InputError
from workers.common.images import EmptyImage, NotAnImage, TooManyPixels, UnreadableImage, UnsupportedImage
from workers.orientation.decode import decode_gray, reduction_factor
from workers.orientation.errors import TruncatedImage
from workers.orientation.exif import write_orientation
from workers.orientation.headers import parse_header, sniff_format


@pytest.mark.parametrize("ext,params,fmt", [
    (".jpg", [cv2.IMWRITE_JPEG_QUALITY, 90], "jpeg"),
    (".jpg", [cv2.IMWRITE_JPEG_PROGRESSIVE, 1], "jpeg"),
    (".jpg", [cv2.IMWRITE_JPEG_RST_INTERVAL, 2], "jpeg"),
    (".png", [], "png"),
    (".webp", [cv2.IMWRITE_WEBP_QUALITY, 80], "webp"),
    (".webp", [cv2.IMWRITE_WEBP_QUALITY, 101], "webp"),  # lossless VP8L
])
def test_header_gives_format_and_size_without_decoding(ext, params, fmt):
    data = encode(asymmetric_image(77, 131), ext, params)
    header = parse_header(data)
    assert (header.format, header.width, header.height, header.damage) == (fmt, 131, 77, None)


def test_vp8x_webp_size_comes_from_the_extended_header():
    data = write_orientation(encode(asymmetric_image(77, 131), ".webp", [cv2.IMWRITE_WEBP_QUALITY, 80]), 6)
    assert data[12:16] == b"VP8X"
    assert (parse_header(data).width, parse_header(data).height) == (131, 77)


def test_reduction_factor_brings_the_long_side_under_the_working_size():
    assert reduction_factor(800, 600, 1000, None) == 1
    assert reduction_factor(2000, 1500, 1000, None) == 2
    assert reduction_factor(4000, 3000, 1000, None) == 4
    assert reduction_factor(6000, 4000, 1000, None) == 8
    assert reduction_factor(20000, 100, 1000, None) == 8
    assert reduction_factor(4000, 3000) == 8  # a 12 MP photo is searched at 500 x 375 by default


def test_reduction_factor_keeps_a_square_photo_to_the_pixels_of_an_oblong_one():
    assert reduction_factor(3464, 3464) == 8  # 433 x 433, as a 4:3 12 MP photo decodes to 500 x 375
    assert reduction_factor(3464, 3464, working_pixels=None) == 4  # by the long side alone: 866 x 866
    assert reduction_factor(1600, 1200) == 2  # 800 x 600: within both
    assert reduction_factor(2480, 3508) == 4  # an A4 scan at 300 dpi: 620 x 877, as oblong as 4:3 or more


def test_beyond_eighth_size_a_square_image_is_resized_to_the_working_pixels():
    data = encode(np.full((7000, 7000), 128, np.uint8), ".png")  # an eighth is 875 x 875: above 900 x 675 pixels
    assert decode_gray(data).gray.shape == (779, 779)
    assert decode_gray(data, working_pixels=None).gray.shape == (875, 875)


def test_twelve_megapixel_jpeg_decodes_at_an_eighth():
    decoded = decode_gray(jpeg(asymmetric_image(3000, 4000), 80))
    assert decoded.gray.shape == (375, 500) and decoded.scale_x == pytest.approx(8.0)


def test_large_jpeg_is_decoded_reduced_with_its_scale():
    data = jpeg(asymmetric_image(1500, 4000), 80)
    decoded = decode_gray(data, working_size=1000)
    assert decoded.gray.shape == (375, 1000) and decoded.gray.dtype == np.uint8
    assert decoded.scale_x == pytest.approx(4.0) and decoded.scale_y == pytest.approx(4.0)


def test_beyond_eighth_size_the_image_is_resized_to_the_working_size():
    decoded = decode_gray(encode(asymmetric_image(60, 9000), ".png"), working_size=1000)
    assert max(decoded.gray.shape) == 1000
    assert decoded.scale_x == pytest.approx(9.0)


def test_decoding_ignores_the_exif_orientation_tag():
    """The detector must see the stored pixels: a tag 6 (show turned 90) must not turn them."""
    image = asymmetric_image(120, 200)
    tagged = write_orientation(jpeg(image), 6)
    assert cv2.imdecode(np.frombuffer(tagged, np.uint8), cv2.IMREAD_GRAYSCALE).shape == (200, 120)  # sanity
    gray = decode_gray(tagged).gray
    expected = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    assert gray.shape == (120, 200)
    assert np.abs(gray.astype(int) - expected).mean() < 3


def test_trailing_bytes_after_the_end_marker_are_accepted():
    data = jpeg() + b"motion-photo trailer" * 10
    assert decode_gray(data).gray.shape == (120, 200)


def test_empty_file():
    with pytest.raises(EmptyImage, match="empty"):
        decode_gray(b"")


@pytest.mark.parametrize("data", [b"hello, this is text", b"%PDF-1.7\n", b"\x00" * 64, b"\xff\xd8"])
def test_not_an_image(data):
    with pytest.raises(NotAnImage, match="not an image"):
        decode_gray(data)


@pytest.mark.parametrize("data,name", [
    (b"GIF89a" + b"\0" * 20, "GIF"), (b"BM" + b"\0" * 40, "BMP"), (b"II+\x00" + b"\0" * 20, "BigTIFF"),
])
def test_recognised_but_unsupported_formats(data, name):
    with pytest.raises(UnsupportedImage, match=name):
        sniff_format(data)


@pytest.mark.parametrize("data,filename,fmt", [
    (b"II*\x00" + b"\0" * 20, "scan.tif", "tiff"), (b"MM\x00*" + b"\0" * 20, None, "tiff"),
    (b"II*\x00" + b"\0" * 20, "IMG_0001.NEF", "raw"), (b"II*\x00" + b"\0" * 20, "a.dng", "raw"),
    (b"II*\x00\x10\x00\x00\x00CR\x02\x00" + b"\0" * 8, "x.bin", "raw"),
    (b"\0\0\0\x18ftypheic" + b"\0" * 20, None, "heif"), (b"\0\0\0\x1cftypavif\0\0\0\0avifmif1", None, "avif"),
    (b"\0\0\0\x1cftypmif1\0\0\0\0mif1heic", None, "heif"),
])
def test_library_formats_are_recognised(data, filename, fmt):
    assert sniff_format(data, filename) == fmt


@pytest.mark.parametrize("cut", [0.3, 0.6, 0.95])
def test_truncated_jpeg(cut):
    data = jpeg(asymmetric_image(300, 400))
    with pytest.raises(TruncatedImage, match="truncated"):
        decode_gray(data[:int(len(data) * cut)])


def test_truncated_jpeg_is_caught_even_with_an_end_marker_inside_its_thumbnail():
    """The EXIF thumbnail holds its own FF D9: looking for that marker alone would be fooled."""
    data = insert_app1(jpeg(asymmetric_image(300, 400)), rich_exif())
    assert b"\xff\xd9" in data[:len(data) // 2]
    with pytest.raises(TruncatedImage):
        decode_gray(data[:len(data) // 2])


def test_truncated_before_the_size_is_known():
    data = insert_app1(jpeg(), rich_exif())
    with pytest.raises(TruncatedImage):
        decode_gray(data[:200])


def test_truncated_png_and_webp():
    with pytest.raises(TruncatedImage):
        decode_gray(encode(asymmetric_image(), ".png")[:-40])
    with pytest.raises(TruncatedImage):
        decode_gray(encode(asymmetric_image(), ".webp")[:-40])


def test_damaged_jpeg_structure():
    data = jpeg()
    app0_end = parse_header(data).segments[0].end
    with pytest.raises(UnreadableImage, match="expected a marker"):
        decode_gray(data[:app0_end] + b"garbage" + data[app0_end:])


def _jpeg_header_claiming(width: int, height: int) -> bytes:
    """A 40-byte file: SOI, a baseline frame header announcing width x height, EOI (no pixel data)."""
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 17, 8, height, width, 3) + b"\x01\x22\x00\x02\x11\x01\x03\x11\x01"
    return b"\xff\xd8\xff\xe0" + struct.pack(">H", 16) + b"JFIF\0\x01\x01\0\0\x01\0\x01\0\0" + sof + b"\xff\xd9"


def test_decompression_bomb_is_refused_from_its_header():
    bomb = _jpeg_header_claiming(60000, 60000)
    assert len(bomb) < 64
    with pytest.raises(TooManyPixels, match=r"60000x60000 = 3,600,000,000 pixels; the limit is 64,000,000"):
        decode_gray(bomb, max_pixels=64_000_000)
    with pytest.raises(TooManyPixels):  # the size is judged before the missing data
        decode_gray(bomb[:-2], max_pixels=64_000_000)


def test_png_bomb_is_refused_from_its_header():
    ihdr = struct.pack(">II5B", 100000, 100000, 8, 0, 0, 0, 0)
    bomb = b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR" + ihdr + b"\0\0\0\0"
    with pytest.raises(TooManyPixels, match="limit is 1,000"):
        decode_gray(bomb, max_pixels=1000)


def test_real_image_over_the_limit():
    with pytest.raises(TooManyPixels):
        decode_gray(jpeg(asymmetric_image(100, 100)), max_pixels=9999)
    assert decode_gray(jpeg(asymmetric_image(100, 100)), max_pixels=10000).gray.shape == (100, 100)


def test_every_cause_has_its_own_input_error_with_a_code():
    causes = (EmptyImage, NotAnImage, UnsupportedImage, TruncatedImage, UnreadableImage, TooManyPixels)
    assert all(issubclass(cls, images.ImageInputError) and issubclass(cls, InputError) for cls in causes)
    assert len({cls.code for cls in causes}) == 6
