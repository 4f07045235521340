"""What a user can get wrong when sending a photo: one exception class per cause.

Every class derives from :class:`OrientationInputError`, itself the service's
:class:`workers.common.images.ImageInputError` (an :class:`~workers.common.errors.InputError`), so there is one
hierarchy of input errors: a cause the common decoder also knows derives from its class there too, with
the same ``code`` (a short stable identifier for JSON error bodies and reports) and HTTP ``status``
(EmptyFile 400, NotAnImage 415, UnsupportedFormat 415, TooManyPixels 413, TruncatedImage 422, CorruptImage
422, UnwritableExif 422). Each carries a message a person understands.
"""
from __future__ import annotations

from workers.common import images


class OrientationInputError(images.ImageInputError):
    """The photo cannot be analysed or tagged because of what was sent."""

    code = "bad_input"


class EmptyFile(images.EmptyImage, OrientationInputError):
    """Zero bytes were sent."""

    code = "empty_file"


class NotAnImage(images.NotAnImage, OrientationInputError):
    """The bytes are not an image in any format we recognise."""

    code = "not_an_image"


class UnsupportedFormat(images.UnsupportedImage, OrientationInputError):
    """An image, but in a format this operation does not handle (GIF, HEIC, PNG for tagging, ...)."""

    code = "unsupported_format"


class TruncatedImage(OrientationInputError):
    """The file ends before the image data does (an interrupted upload or copy)."""

    code = "truncated_image"
    status = 422


class CorruptImage(images.UnreadableImage, OrientationInputError):
    """The file is structurally damaged or the decoder cannot read it."""

    code = "corrupt_image"


class TooManyPixels(images.TooManyPixels, OrientationInputError):
    """The header announces more pixels than the configured limit (a decompression bomb guard)."""

    code = "too_many_pixels"


class UnwritableExif(OrientationInputError):
    """The EXIF block cannot take the Orientation tag without losing data (it would exceed 64 KiB)."""

    code = "unwritable_exif"
    status = 422
