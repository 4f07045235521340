"""Meshes for the face tests: one synthetic face, and a mesh file read back."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from workers.faces.mesh import Mesh, read_mesh
from workers.faces.synthetic import NEUTRAL, expression_face, random_person, template


def demo_mesh(expression: str = NEUTRAL, intensity: float = 0.6, seed: int = 1234) -> Mesh:
    """One synthetic face mesh of a person not in the default training set."""
    tpl = template()
    person = random_person(np.random.default_rng(seed))
    return Mesh.from_faces(expression_face(tpl, person, expression, intensity), tpl.faces)


def load_mesh(path: str | Path) -> Mesh:
    """A mesh file read from disk as the engine reads uploaded bytes."""
    path = Path(path)
    return read_mesh(path.read_bytes(), path.name)
