"""What a user can get wrong when sending a photo, beyond what every image decoder refuses.

The causes the service's one checked decoder also knows are its classes (:mod:`workers.common.images`):
:class:`~workers.common.images.EmptyImage` 400, :class:`~workers.common.images.NotAnImage` 415,
:class:`~workers.common.images.UnsupportedImage` 415, :class:`~workers.common.images.TooManyPixels` 413 and
:class:`~workers.common.images.UnreadableImage` 422 (``corrupt_image``). The orientation engine adds the two below;
ExifTool's own failures are :mod:`workers.orientation.exiftool`'s. Each is an
:class:`~workers.common.errors.InputError` (its ``code`` and HTTP ``status``) with a message a person understands.
"""
from __future__ import annotations

from workers.common import images
from workers.common.errors import InputError


class TruncatedImage(images.ImageInputError):
    """The file ends before the image data does (an interrupted upload or copy)."""

    code = "truncated_image"
    status = 422


class UnwritableExif(InputError):
    """The EXIF block cannot take the Orientation tag without losing data (it would exceed 64 KiB)."""

    code = "unwritable_exif"
    status = 422
