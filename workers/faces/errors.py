"""The errors a user of the face transformer can cause."""
from __future__ import annotations

from workers.common.errors import InputError


class FaceInputError(InputError):
    """An unusable input: not a mesh, wrong topology, NaN vertices, unknown impression, Q out of range."""

    code = "bad_face_input"


class DatasetError(FaceInputError):
    """A training dataset zip that cannot be used: damaged, unsafe or over a zip limit, or its manifest wrong."""

    code = "invalid_dataset"
