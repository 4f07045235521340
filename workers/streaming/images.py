"""Image bytes <-> arrays for frames: size from the header (before decoding), decode, encode."""
from __future__ import annotations

import struct

import cv2
import numpy as np

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# JPEG SOFn markers carry the frame size (C4 DHT, C8 JPG and CC DAC share the range but do not).
_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


class ImageError(ValueError):
    """Image bytes that cannot be used; the message says why."""


def image_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) read from a JPEG's SOF or a PNG's IHDR without decoding; None when the
    bytes are neither or the header is cut short."""
    if data[:8] == _PNG_SIGNATURE and len(data) >= 24 and data[12:16] == b"IHDR":
        w, h = struct.unpack(">II", data[16:24])
        return int(w), int(h)
    if data[:2] != b"\xff\xd8":
        return None
    pos = 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            return None
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker in (0x01, *range(0xD0, 0xD8)):
            pos += 2
            continue
        (length,) = struct.unpack(">H", data[pos + 2:pos + 4])
        if marker in _SOF and pos + 9 <= len(data):
            h, w = struct.unpack(">HH", data[pos + 5:pos + 9])
            return int(w), int(h)
        if marker == 0xDA:  # start of scan before any SOF
            return None
        pos += 2 + length
    return None


def decode_image(data: bytes, size: tuple[int, int]) -> np.ndarray:
    """Decode a JPEG or PNG that must be ``size`` = (width, height): (H, W, 3) uint8 BGR.

    The size is checked from the header first, so an oversized image is refused undecoded;
    EXIF orientation is ignored (the calibration is of the stored pixels)."""
    found = image_size(data)
    if found is None:
        raise ImageError("is not a JPEG or PNG image")
    if found != tuple(size):
        raise ImageError(f"is {found[0]}x{found[1]}, the calibration says {size[0]}x{size[1]}")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
    if img is None:
        raise ImageError("does not decode (damaged or truncated)")
    return img


def encode_jpeg(image: np.ndarray, quality: int = 85) -> bytes:
    """JPEG bytes of an (H, W, 3) uint8 BGR image."""
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ImageError("JPEG encoding failed")
    return buf.tobytes()


def encode_png(image: np.ndarray, level: int = 1) -> bytes:
    """PNG bytes (lossless) of an (H, W[, C]) uint8 or uint16 image; ``level`` 0..9 (1: fast)."""
    ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, int(level)])
    if not ok:
        raise ImageError("PNG encoding failed")
    return buf.tobytes()
