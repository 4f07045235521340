"""The error a user of the depth engine can cause."""
from __future__ import annotations

from workers.common.errors import InputError

STATUS_BY_CODE = {"too_many_pixels": 413, "not_an_image": 415, "unsupported_format": 415, "corrupt_image": 422,
                  "output_too_large": 422, "not_a_video": 415, "corrupt_video": 422, "too_many_frames": 413}
"""The HTTP status of each cause (as the photo routes answer for the same image problems); others are 400."""


class DepthInputError(InputError):
    """Unusable input (sizes, bit depth, file length, method, factor); the message says what was expected.

    ``code`` is ``bad_depth_input`` unless a cause says more (an image's ``too_many_pixels``, ``not_an_image``,
    ...; ``output_too_large`` for a requested output size); the status follows the code (:data:`STATUS_BY_CODE`).
    """

    code = "bad_depth_input"

    def __init__(self, message: str, code: str | None = None, status: int | None = None) -> None:
        super().__init__(message, code, status or STATUS_BY_CODE.get(code or self.code, 400))
