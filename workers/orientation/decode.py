"""Decoding a photo for orientation detection: stored pixels, grey, at a reduced size, checked first.

The header is read and checked before decoding (:mod:`workers.orientation.headers`): an empty
file, a non-image, an unsupported format, a decompression bomb and a truncated or damaged file
are each refused with their own :class:`~workers.common.errors.InputError`. Pixels are decoded with
``cv2.IMREAD_IGNORE_ORIENTATION`` (the detector must see the stored pixels, not the ones an
existing EXIF tag would show) and, for JPEG, with libjpeg's DCT scaling
(``IMREAD_REDUCED_GRAYSCALE_2/4/8``), which skips most of the inverse-DCT work of a large photo.
"""
from __future__ import annotations

import io
from dataclasses import dataclass

import cv2
import numpy as np

from workers.common import images
from workers.orientation.headers import ImageHeader, check_header, parse_header

WORKING_SIZE = 900
"""Longest side (px) of the decoded image handed to the detectors (a 4000 x 3000 photo decodes at 1/8 to
500 x 375). Chosen on the dev photos (``benchmarks/orientation.py``)."""
WORKING_PIXELS = 900 * 675
"""Most pixels of the decoded image handed to the detectors: those of a 4:3 photo at the working size, so that an
image as oblong as 4:3 or more is decoded as before, and a square 12 MP photo (3464 x 3464) decodes at 1/8 to
433 x 433 as a 4:3 one decodes to 500 x 375, not at 1/4 to 866 x 866 (1.2 times the pixels of the budget, four times
those of the 4:3 photo, and about twice the face detector's CPU)."""
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


def reduction_factor(width: int, height: int, working_size: int = WORKING_SIZE,
                     working_pixels: int | None = WORKING_PIXELS) -> int:
    """The smallest of 1, 2, 4, 8 that brings the long side (px) to at most ``working_size`` and the pixels to at most
    ``working_pixels`` (None: any number); else 8."""
    for factor in (1, 2, 4):
        w, h = -(-width // factor), -(-height // factor)
        if max(w, h) <= working_size and (working_pixels is None or w * h <= working_pixels):
            return factor
    return 8


def decode_gray(data: bytes, max_pixels: int = DEFAULT_MAX_PIXELS, working_size: int = WORKING_SIZE,
                filename: str | None = None, header: ImageHeader | None = None,
                working_pixels: int | None = WORKING_PIXELS) -> DecodedImage:
    """Check and decode ``data`` to grey with its long side <= ``working_size`` and at most ``working_pixels`` pixels
    (None: any number).

    JPEG, PNG, WebP and TIFF: the stored pixels (any Orientation tag ignored). HEIF and AVIF: the
    *displayed* image (their irot/imir applied, as every HEIF reader does; ``header`` keeps the coded
    size). RAW: the largest embedded JPEG preview (stored pixels; needs exiftool). Raises EmptyImage,
    NotAnImage, UnsupportedImage, TooManyPixels (header size above ``max_pixels``, before any
    decoding), TruncatedImage or UnreadableImage (and ExifToolUnavailable for a RAW file without exiftool).
    ``header``: what :func:`parse_header` said of ``data``, when the caller has it (else it is parsed here).
    """
    if header is None:
        header = parse_header(data, filename)
    check_header(header, max_pixels)
    if header.format in ("heif", "avif"):
        return _fit(_decode_heif(data, header), header, working_size, working_pixels)
    if header.format == "raw":
        preview = raw_preview(data)
        decoded = decode_gray(preview, max_pixels, working_size, working_pixels=working_pixels)
        return DecodedImage(decoded.gray, ImageHeader("raw", decoded.header.width, decoded.header.height),
                            decoded.scale_x, decoded.scale_y)
    if header.format == "tiff":
        data = _tiff_without_orientation(data, header)
    factor = reduction_factor(header.width, header.height, working_size, working_pixels)
    flags = _REDUCED_FLAGS[factor] | cv2.IMREAD_IGNORE_ORIENTATION
    try:  # the service's one checked decoder (its own header check agrees with the one above)
        gray = images.decode_image(data, flags, max_pixels)
    except (images.TooManyPixels, images.UnreadableImage):
        raise
    except images.ImageInputError as exc:  # the header read above is an image's: the decoder failing means damage
        raise images.UnreadableImage(str(exc)) from None
    if gray.ndim == 3:  # a TIFF OpenCV decodes only in colour, or with alpha
        gray = cv2.cvtColor(gray, cv2.COLOR_BGRA2GRAY if gray.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    if gray.dtype != np.uint8:  # 16-bit TIFF
        gray = (gray.astype(np.float32) * (255.0 / max(1.0, float(np.iinfo(gray.dtype).max)))).astype(np.uint8)
    return _fit(gray, header, working_size, working_pixels)


def decode_at_least(data: bytes, long_side: float, max_pixels: int = DEFAULT_MAX_PIXELS, filename: str | None = None,
                    header: ImageHeader | None = None) -> DecodedImage:
    """``data`` decoded to grey with its long side at least ``long_side`` px (or its full size when smaller): a JPEG
    at the smallest DCT scale (1/8, 1/4, 1/2, 1) that is large enough, any other format in full then reduced. The
    same checks as :func:`decode_gray`."""
    if header is None:
        header = parse_header(data, filename)
    full = max(header.width, header.height)
    factor = next((f for f in (8, 4, 2) if -(-full // f) >= long_side), 1)
    return decode_gray(data, max_pixels, max(1, -(-full // factor)), filename=filename, header=header,
                       working_pixels=None)


def _fit(gray: np.ndarray, header: ImageHeader, working_size: int, working_pixels: int | None) -> DecodedImage:
    """``gray`` reduced to a long side <= ``working_size`` and at most ``working_pixels`` pixels (INTER_AREA), with its
    scale to the decoded size."""
    full_h, full_w = gray.shape[:2]
    s = working_size / max(gray.shape)
    if working_pixels is not None:
        s = min(s, (working_pixels / (full_h * full_w)) ** 0.5)
    if s < 1:  # beyond what DCT scaling (at most 1/8) reaches, or a format without it
        size = (max(1, round(gray.shape[1] * s)), max(1, round(gray.shape[0] * s)))
        gray = cv2.resize(gray, size, interpolation=cv2.INTER_AREA)
    if header.format in ("heif", "avif"):  # boxes are in the displayed image: its size, not the coded one
        return DecodedImage(gray, header, full_w / gray.shape[1], full_h / gray.shape[0])
    return DecodedImage(gray, header, header.width / gray.shape[1], header.height / gray.shape[0])


def _tiff_without_orientation(data: bytes, header: ImageHeader) -> bytes:
    """The TIFF with IFD0's Orientation set to 1 in memory: OpenCV 4.14 fails on IMREAD_IGNORE_ORIENTATION
    with an oriented TIFF, and applying the tag is not what detection wants."""
    from workers.orientation.exif import _set_orientation
    from workers.orientation.headers import read_ifd0, tiff_values

    try:
        ifd0 = header.ifd0 if header.ifd0 is not None else read_ifd0(data)
        tags = ifd0.tags
        values = tiff_values(data, ifd0.endian, tags[274]) if 274 in tags else None
        return _set_orientation(data, 1, ifd0) if values and values[0] != 1 else data
    except ValueError as exc:
        raise images.UnreadableImage(f"the TIFF's first image directory cannot be read: {exc}") from None


def _decode_heif(data: bytes, header: ImageHeader) -> np.ndarray:
    """The displayed image of a HEIF (pillow-heif: libheif applies irot/imir) or AVIF (Pillow decodes the
    coded image; its irot/imir are applied here) as (H, W) uint8 grey."""
    from PIL import Image

    from workers.orientation.bmff import read_heif
    from workers.orientation.geometry import apply_orientation, heif_orientation

    try:
        if header.format == "heif":
            import pillow_heif

            heif = pillow_heif.open_heif(io.BytesIO(data), convert_hdr_to_8bit=True)
            image = heif.to_pillow()
        else:
            image = Image.open(io.BytesIO(data))
            image.load()
        gray = np.asarray(image.convert("L"))
    except (OSError, ValueError, RuntimeError, SyntaxError) as exc:
        raise images.UnreadableImage(f"the {header.format.upper()} image cannot be decoded ({exc})") from None
    if header.format == "avif":
        gray = np.ascontiguousarray(apply_orientation(gray, heif_orientation(read_heif(data).transforms)))
    return gray


def raw_preview(data: bytes) -> bytes:
    """The largest JPEG preview embedded in a camera RAW file (JpgFromRaw, PreviewImage, OtherImage or
    ThumbnailImage), read by exiftool. Raises UnsupportedImage when it has none."""
    import tempfile
    from pathlib import Path

    from workers.orientation import exiftool

    with tempfile.TemporaryDirectory(prefix="sweepcast-raw-") as tmp:
        path = Path(tmp) / "photo.raw"
        path.write_bytes(data)
        best = b""
        for tag in ("JpgFromRaw", "PreviewImage", "OtherImage", "ThumbnailImage"):
            out = exiftool.run(["-b", f"-{tag}", str(path)]).stdout
            if out[:3] == b"\xff\xd8\xff" and len(out) > len(best):
                best = out
    if not best:
        raise images.UnsupportedImage("the RAW file has no embedded JPEG preview to analyse")
    return best
