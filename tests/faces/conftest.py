"""Fixtures of the face transformer tests: a small synthetic training set and model, built once."""
from __future__ import annotations

import pytest

from workers.faces.synthetic import generate_dataset
from workers.faces.train import train_face_model


@pytest.fixture(scope="session")
def face_dataset():
    """12 synthetic people x (neutral + 6 expressions) = 84 faces."""
    return generate_dataset(people=12, seed=5)


@pytest.fixture(scope="session")
def face_model(face_dataset):
    return train_face_model(face_dataset)


@pytest.fixture(scope="session")
def default_model():
    """The service's default model: 40 synthetic people x 7 faces (the paper's design)."""
    from workers.faces.job import build_default_model

    return build_default_model()
