"""Image bytes <-> arrays for frames: size from the header (before decoding), decode, encode."""
from __future__ import annotations

import cv2
import numpy as np

from workers.common import images


class ImageError(ValueError):
    """Image bytes that cannot be used; the message says why."""


def image_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) read from the header without decoding (:func:`workers.common.images.read_image_size`);
    None when the bytes are not a supported image or the header is damaged."""
    try:
        size = images.read_image_size(data)
    except images.ImageInputError:
        return None
    return size.width, size.height


def decode_image(data: bytes, size: tuple[int, int]) -> np.ndarray:
    """Decode an image that must be ``size`` = (width, height): (H, W, 3) uint8 BGR.

    The size is checked from the header first, so an oversized image is refused undecoded;
    EXIF orientation is ignored (the calibration is of the stored pixels)."""
    found = image_size(data)
    if found is None:
        raise ImageError(f"is not a readable image ({images.SUPPORTED})")
    if found != tuple(size):
        raise ImageError(f"is {found[0]}x{found[1]}, the calibration says {size[0]}x{size[1]}")
    try:
        return images.decode_image(data, cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION, found[0] * found[1])
    except images.ImageInputError:
        raise ImageError("does not decode (damaged or truncated)") from None


def decode_stored(data: bytes, size: tuple[int, int]) -> np.ndarray:
    """Decode an image the service stored for a camera of ``size`` = (width, height), at that size or
    smaller (a live session's background model is kept at its working size): (h, w, 3) uint8 BGR."""
    found = image_size(data)
    if found is None or found[0] > size[0] or found[1] > size[1]:
        raise ImageError(f"is not a stored image of at most {size[0]}x{size[1]}")
    try:
        return images.decode_image(data, cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION, found[0] * found[1])
    except images.ImageInputError:
        raise ImageError("does not decode (damaged or truncated)") from None


_DCT_FLAGS = {8: cv2.IMREAD_REDUCED_COLOR_8, 4: cv2.IMREAD_REDUCED_COLOR_4, 2: cv2.IMREAD_REDUCED_COLOR_2}


def reduced_size(size: tuple[int, int], factor: int) -> tuple[int, int]:
    """(width, height) of a ``size`` image shrunk by ``factor``: round(W / factor) x round(H / factor),
    at least 1 (the size :func:`workers.streaming.session.shrunk_camera` calibrates)."""
    return max(1, round(size[0] / factor)), max(1, round(size[1] / factor))


def decode_reduced(data: bytes, size: tuple[int, int], factor: int) -> np.ndarray:
    """Decode an image that must be ``size`` = (width, height), shrunk by the integer ``factor`` >= 1:
    (round(H / factor), round(W / factor), 3) uint8 BGR.

    As :func:`decode_image` (header checked first, EXIF orientation ignored), but a JPEG is decoded
    by libjpeg's DCT scaling at 1/2, 1/4 or 1/8 (the largest that divides ``factor``), which skips
    most of the inverse-DCT and colour work; what DCT scaling does not reach (factor 3, 6, ...; sizes
    that are no multiple of 8) is area-averaged after. Pixel centres map as u' = (u + 0.5) / factor - 0.5."""
    if factor < 1:
        raise ValueError(f"factor must be >= 1, got {factor}")
    found = image_size(data)
    if found is None:
        raise ImageError(f"is not a readable image ({images.SUPPORTED})")
    if found != tuple(size):
        raise ImageError(f"is {found[0]}x{found[1]}, the calibration says {size[0]}x{size[1]}")
    dct = next((d for d in (8, 4, 2) if factor % d == 0), 1)
    flags = _DCT_FLAGS.get(dct, cv2.IMREAD_COLOR) | cv2.IMREAD_IGNORE_ORIENTATION
    try:
        img = images.decode_image(data, flags, found[0] * found[1])
    except images.ImageInputError:
        raise ImageError("does not decode (damaged or truncated)") from None
    w, h = reduced_size(found, factor)
    if img.shape[:2] != (h, w):
        img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    return img


def encode_jpeg(image: np.ndarray, quality: int = 85) -> bytes:
    """JPEG bytes of an (H, W, 3) uint8 BGR image."""
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ImageError("JPEG encoding failed")
    return buf.tobytes()
