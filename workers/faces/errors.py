"""The error a user of the face transformer can cause (the web layer maps it to a 4xx)."""
from __future__ import annotations


class FaceInputError(ValueError):
    """An unusable input: not a mesh, wrong topology, NaN vertices, unknown impression, Q out of range."""
