"""The error a user of the depth engine can cause."""
from __future__ import annotations

from workers.common.jobctx import JobInputError


class DepthInputError(ValueError, JobInputError):
    """Unusable input (sizes, bit depth, file length, method, factor); the message says what was expected.

    A ``ValueError`` for library callers and a ``JobInputError`` for the job system, so the web
    layer can map it to a 4xx and a job fails at once without retries. ``code`` is a short stable
    identifier for JSON error bodies: ``bad_depth_input`` unless a cause says more (an image's
    ``too_many_pixels``, ``not_an_image``, ...; ``output_too_large`` for a requested output size).
    """

    code = "bad_depth_input"

    def __init__(self, message: str, code: str | None = None) -> None:
        super().__init__(message)
        if code is not None:
            self.code = code
