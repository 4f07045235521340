"""What a user can get wrong when sending a photo: one exception class per cause.

Every class derives from :class:`OrientationInputError` (a ``ValueError``) and carries a message
a person understands; ``code`` is a short stable identifier for JSON error bodies and reports.
Suggested HTTP statuses: EmptyFile 400, NotAnImage 415, UnsupportedFormat 415, TooManyPixels 413,
TruncatedImage 422, CorruptImage 422, UnwritableExif 422.
"""
from __future__ import annotations


class OrientationInputError(ValueError):
    """The photo cannot be analysed or tagged because of what was sent."""

    code = "bad_input"


class EmptyFile(OrientationInputError):
    """Zero bytes were sent."""

    code = "empty_file"


class NotAnImage(OrientationInputError):
    """The bytes are not an image in any format we recognise."""

    code = "not_an_image"


class UnsupportedFormat(OrientationInputError):
    """An image, but in a format this operation does not handle (GIF, HEIC, PNG for tagging, ...)."""

    code = "unsupported_format"


class TruncatedImage(OrientationInputError):
    """The file ends before the image data does (an interrupted upload or copy)."""

    code = "truncated_image"


class CorruptImage(OrientationInputError):
    """The file is structurally damaged or the decoder cannot read it."""

    code = "corrupt_image"


class TooManyPixels(OrientationInputError):
    """The header announces more pixels than the configured limit (a decompression bomb guard)."""

    code = "too_many_pixels"


class UnwritableExif(OrientationInputError):
    """The EXIF block cannot take the Orientation tag without losing data (it would exceed 64 KiB)."""

    code = "unwritable_exif"
