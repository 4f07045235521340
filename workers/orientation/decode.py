"""Decoding a photo for orientation detection: stored pixels, grey, at a reduced size, checked first.

The header is read and checked before decoding (:mod:`workers.orientation.headers`): an empty
file, a non-image, an unsupported format, a decompression bomb and a truncated or damaged file
are each refused with their own :class:`OrientationInputError`. Pixels are decoded with
``cv2.IMREAD_IGNORE_ORIENTATION`` (the detector must see the stored pixels, not the ones an
existing EXIF tag would show) and, for JPEG, with libjpeg's DCT scaling
(``IMREAD_REDUCED_GRAYSCALE_2/4/8``), which skips most of the inverse-DCT work of a large photo.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from workers.common import images
from workers.orientation.errors import (CorruptImage, EmptyFile, NotAnImage, OrientationInputError, TooManyPixels,
                                        TruncatedImage, UnsupportedFormat, UnwritableExif)
from workers.orientation.headers import ImageHeader, check_header, parse_header

__all__ = [
    "CorruptImage", "DEFAULT_MAX_PIXELS", "DecodedImage", "EmptyFile", "NotAnImage", "OrientationInputError",
    "TooManyPixels", "TruncatedImage", "UnsupportedFormat", "UnwritableExif", "WORKING_SIZE", "decode_gray",
    "reduction_factor",
]

WORKING_SIZE = 900
"""Longest side (px) of the decoded image handed to the detectors. A 12-megapixel photo
(4000 x 3000) decodes at 1/8 to 500 x 375; on the dev photos 900 lost nothing against 1024."""
DEFAULT_MAX_PIXELS = images.DEFAULT_MAX_PIXELS
"""Default pixel limit (width x height) when the caller gives none."""

_REDUCED_FLAGS = {
    1: cv2.IMREAD_GRAYSCALE,
    2: cv2.IMREAD_REDUCED_GRAYSCALE_2,
    4: cv2.IMREAD_REDUCED_GRAYSCALE_4,
    8: cv2.IMREAD_REDUCED_GRAYSCALE_8,
}


@dataclass(frozen=True)
class DecodedImage:
    """A photo's stored pixels in grey at working size, and how they map to the stored image."""

    gray: np.ndarray
    """(h, w) uint8, the stored orientation (any EXIF tag ignored)."""
    header: ImageHeader
    scale_x: float
    """Stored-image pixels per decoded pixel along x (>= 1)."""
    scale_y: float
    """Stored-image pixels per decoded pixel along y (>= 1)."""


def reduction_factor(width: int, height: int, working_size: int = WORKING_SIZE) -> int:
    """The smallest of 1, 2, 4, 8 that brings the long side (px) to at most ``working_size``; else 8."""
    long_side = max(width, height)
    for factor in (1, 2, 4):
        if -(-long_side // factor) <= working_size:
            return factor
    return 8


def decode_gray(data: bytes, max_pixels: int = DEFAULT_MAX_PIXELS, working_size: int = WORKING_SIZE) -> DecodedImage:
    """Check and decode ``data`` (JPEG, PNG or WebP bytes) to grey with its long side <= ``working_size``.

    Raises EmptyFile, NotAnImage, UnsupportedFormat, TooManyPixels (header size above
    ``max_pixels``, before any decoding), TruncatedImage or CorruptImage.
    """
    header = parse_header(data)
    check_header(header, max_pixels)
    factor = reduction_factor(header.width, header.height, working_size)
    flags = _REDUCED_FLAGS[factor] | cv2.IMREAD_IGNORE_ORIENTATION
    try:  # the service's one checked decoder (its own header check agrees with the one above)
        gray = images.decode_image(data, flags, max_pixels)
    except images.TooManyPixels as exc:
        raise TooManyPixels(str(exc)) from None
    except images.ImageInputError as exc:
        raise CorruptImage(str(exc)) from None
    long_side = max(gray.shape)
    if long_side > working_size:  # beyond what DCT scaling (at most 1/8) reaches
        s = working_size / long_side
        size = (max(1, round(gray.shape[1] * s)), max(1, round(gray.shape[0] * s)))
        gray = cv2.resize(gray, size, interpolation=cv2.INTER_AREA)
    return DecodedImage(gray, header, header.width / gray.shape[1], header.height / gray.shape[0])
