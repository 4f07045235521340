"""The one image decoder of the service: the pixel size is read from the header and checked
before a single pixel is decoded.

OpenCV decodes whatever the bytes claim, and its own guard (``OPENCV_IO_MAX_IMAGE_PIXELS``) is a
process-wide constant read when ``cv2`` is imported, so a per-service limit cannot go through it.
Every decode of bytes a user sent goes through :func:`decode_image` instead:

- Pillow identifies the container and reads its header (it decodes no pixels until asked): JPEG,
  PNG, WebP, BMP, TIFF and PGM/PPM are accepted; other formats Pillow knows (GIF, ...) are refused
  as unsupported, bytes it cannot identify as not an image;
- the header's width x height is checked against ``max_pixels``, so a decompression bomb (a small
  file that declares a huge image) is refused undecoded;
- OpenCV then decodes (the engines work on its arrays); empty and undecodable bytes raise a clear
  error instead of ``cv2.error``.

Errors derive from :class:`ImageInputError` (an :class:`~workers.common.errors.InputError`: ``code`` and the
HTTP ``status`` for JSON error bodies); engines wrap them in their own input-error type or let them through.
"""
from __future__ import annotations

import io
from dataclasses import dataclass

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

from workers.common.errors import InputError
from workers.settings import WorkerSettings, worker_settings

MAX_PIXELS_ENV = "SWEEPCAST_MAX_IMAGE_PIXELS"
DEFAULT_MAX_PIXELS: int = WorkerSettings.model_fields["max_image_pixels"].default
"""Pixel limit (width x height) when neither the caller nor the environment gives one (the setting's default)."""
SUPPORTED = "JPEG, PNG, WebP, BMP, TIFF or PGM/PPM"
_SUPPORTED_FORMATS = frozenset({"JPEG", "PNG", "WEBP", "BMP", "TIFF", "PPM"})  # Pillow's names
# The limit is ours (checked below with the header's size); Pillow's own bomb check would refuse or warn
# with other thresholds before ours runs. The service opens images with Pillow only here.
Image.MAX_IMAGE_PIXELS = None


class ImageInputError(InputError):
    """Image bytes a user sent that cannot be decoded; the message says why."""

    code = "bad_image"
    status = 400


class EmptyImage(ImageInputError):
    code = "empty_file"


class NotAnImage(ImageInputError):
    code = "not_an_image"
    status = 415


class UnsupportedImage(ImageInputError):
    code = "unsupported_format"
    status = 415


class TooManyPixels(ImageInputError):
    code = "too_many_pixels"
    status = 413


class UnreadableImage(ImageInputError):
    code = "corrupt_image"
    status = 422


@dataclass(frozen=True)
class ImageSize:
    """What a header says: the container format and the pixel size."""

    format: str
    width: int
    height: int

    @property
    def pixels(self) -> int:
        return self.width * self.height


def max_pixels_from_env() -> int:
    """The pixel limit of this process: ``$SWEEPCAST_MAX_IMAGE_PIXELS`` (set for the service's Ray
    workers from the setting ``max_image_pixels``), else :data:`DEFAULT_MAX_PIXELS`."""
    return worker_settings().max_image_pixels


def check_pixels(width: int, height: int, max_pixels: int | None = None, what: str = "the image") -> None:
    """TooManyPixels when ``width`` x ``height`` is over ``max_pixels`` (None: the process's limit)."""
    limit = max_pixels if max_pixels is not None else max_pixels_from_env()
    if width * height > limit:
        raise TooManyPixels(f"{what} is {width}x{height} = {width * height:,} pixels; the limit is {limit:,} pixels")


def read_image_size(data: bytes) -> ImageSize:
    """Format and pixel size from the header of ``data``, never decoding pixels.

    Raises EmptyImage, NotAnImage, UnsupportedImage, or UnreadableImage (a header giving an empty size).
    """
    if len(data) == 0:
        raise EmptyImage("the file is empty (0 bytes)")
    try:
        with Image.open(io.BytesIO(data)) as img:  # reads the header only
            fmt, (width, height) = img.format or "?", img.size
    except UnidentifiedImageError:
        raise NotAnImage(f"not a readable image: the bytes (starting {data[:8].hex(' ')}) are no {SUPPORTED} "
                         "header, or it is damaged or truncated") from None
    except (OSError, SyntaxError, ValueError) as exc:
        raise UnreadableImage(f"the image header is damaged ({exc})") from None
    if fmt not in _SUPPORTED_FORMATS:
        raise UnsupportedImage(f"{fmt} images are not supported; send {SUPPORTED}")
    if width <= 0 or height <= 0:
        raise UnreadableImage(f"the {fmt} header gives an empty size {width}x{height}")
    return ImageSize(fmt, int(width), int(height))


def encode_png(image: np.ndarray, level: int | None = 1) -> bytes:
    """Lossless PNG bytes of an (H, W) or (H, W, C) uint8 or uint16 image (C: 3 BGR or 4 BGRA);
    ``level``: zlib effort 0..9 (1: fast, the files are a few per cent larger than at 9), or None for
    OpenCV's own fast setting (level 1 with one fixed filter: smaller on smooth pictures such as previews).
    Raises ValueError for an image PNG cannot hold (float pixels, ...)."""
    channels = image.shape[2] if image.ndim == 3 else 1
    if image.dtype not in (np.uint8, np.uint16) or image.ndim not in (2, 3) or channels not in (1, 3, 4):
        raise ValueError(f"cannot encode an image of {image.dtype} {image.shape} as PNG")  # OpenCV would cast
    ok, buf = cv2.imencode(".png", image, [] if level is None else [cv2.IMWRITE_PNG_COMPRESSION, int(level)])
    if not ok:  # pragma: no cover - a checked array encodes
        raise ValueError(f"OpenCV failed to encode an image of {image.dtype} {image.shape} as PNG")
    return buf.tobytes()


def decode_image(data: bytes, flags: int, max_pixels: int | None = None) -> np.ndarray:
    """``cv2.imdecode(data, flags)`` after checking the header's size against ``max_pixels``
    (None: :func:`max_pixels_from_env`). Returns the array OpenCV gives for ``flags``, e.g.
    (H, W, 3) uint8 BGR for ``IMREAD_COLOR``, (H, W) uint8/uint16 grey for a grey PNG with
    ``IMREAD_UNCHANGED``. Raises an :class:`ImageInputError` for anything a user can get wrong.
    """
    size = read_image_size(data)
    check_pixels(size.width, size.height, max_pixels)
    try:
        img = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    except cv2.error as exc:
        raise UnreadableImage(f"the {size.format} decoder failed: {exc.err or exc}") from None
    if img is None or img.size == 0:
        raise UnreadableImage(f"the {size.format} image data cannot be decoded (damaged or truncated)")
    return img
