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


def encode_jpeg(image: np.ndarray, quality: int = 85) -> bytes:
    """JPEG bytes of an (H, W, 3) uint8 BGR image."""
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ImageError("JPEG encoding failed")
    return buf.tobytes()
