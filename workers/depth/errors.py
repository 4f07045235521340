"""The error a user of the depth engine can cause."""
from __future__ import annotations

from workers.common.jobctx import JobInputError


class DepthInputError(ValueError, JobInputError):
    """Unusable input (sizes, bit depth, file length, method, factor); the message says what was expected.

    A ``ValueError`` for library callers and a ``JobInputError`` for the job system, so the web
    layer can map it to a 4xx and a job fails at once without retries.
    """
