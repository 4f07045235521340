"""The errors a user of the depth engine can cause: one class per cause that has its own HTTP status.

An image the engine cannot decode is the common decoder's error (:mod:`workers.common.images`: ``not_an_image``
415, ``too_many_pixels`` 413, ...), passed on with the input it came from (:meth:`InputError.about`).
"""
from __future__ import annotations

from workers.common.errors import InputError


class DepthInputError(InputError):
    """Unusable input (sizes, bit depth, file length, method, factor); the message says what was expected.

    ``code`` ``bad_depth_input``, status 400, unless a subclass below names the cause."""

    code = "bad_depth_input"
    status = 400


class OutputTooLarge(DepthInputError):
    """The requested output (an upsampled map, a synthesised view) is over the size limit."""

    code = "output_too_large"
    status = 422


class PartialFrames(DepthInputError):
    """A raw YUV sequence whose length is not a whole number of frames (cut short, or the wrong format)."""

    status = 422


class NotAVideo(DepthInputError):
    """The bytes are no video container, or hold no video stream."""

    code = "not_a_video"
    status = 415


class UnsupportedVideo(DepthInputError):
    """A video, but not 8-bit H.264 or HEVC."""

    code = "unsupported_format"
    status = 415


class CorruptVideo(DepthInputError):
    """A depth video that is damaged: no frame size, no frames, frames of another size, or decoding failed."""

    code = "corrupt_video"
    status = 422


class TooManyFrames(DepthInputError):
    """More frames than the limit of one sequence."""

    code = "too_many_frames"
    status = 413
