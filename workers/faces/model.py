"""The trained face model (morphable model, identity model, impressions) saved as one ``.npz``.

The chain is one way: :mod:`workers.faces.morphable` (the maths type) <- :mod:`workers.faces.neutral`
(the identity model) <- this module (the saved bundle of both with the impressions' transfers).
"""
from __future__ import annotations

import io
import json
import os
import uuid
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from workers.faces.errors import FaceInputError
from workers.faces.mesh import Mesh
from workers.faces.morphable import MorphableModel
from workers.faces.neutral import IdentityModel
from workers.faces.transfer import SvmTransfer

FORMAT_VERSION = 1


@dataclass(eq=False)
class FaceModel:
    """A trained face transformer: the morphable model plus one Fisher vector and one SVC per impression.

    ``fisher``: (I, K) unit rows in the order of ``impressions``; ``svms``: one
    :class:`SvmTransfer` per impression; ``q_unit``: the length in parameter space of Q = 1
    (the RMS norm of the training expressions' displacements, in mesh units), so Q = 1 is a step
    as large as a typical training expression; ``m``, ``n``: default neighbour counts of eq. 5;
    ``meta``: JSON-able training facts (settings, counts, accuracies); ``identity``: the identity
    PCA used to estimate a person's neutral face when none is given (see :mod:`workers.faces.neutral`).
    """

    morph: MorphableModel
    impressions: tuple[str, ...]
    fisher: np.ndarray
    svms: tuple[SvmTransfer, ...]
    q_unit: float
    m: int = 10
    n: int = 10
    meta: dict[str, Any] = field(default_factory=dict)
    identity: IdentityModel | None = None

    def impression_index(self, impression: str) -> int:
        """Index of ``impression``; raises FaceInputError naming the known ones."""
        try:
            return self.impressions.index(impression)
        except ValueError:
            raise FaceInputError(
                f"unknown impression {impression!r}; this model knows: {', '.join(self.impressions)}"
            ) from None

    def summary(self) -> dict[str, Any]:
        """A JSON-able description (for listings and ``summary.json``)."""
        return {
            "impressions": list(self.impressions),
            "n_vertices": self.morph.n_vertices,
            "n_faces": self.morph.topology.n_faces,
            "n_components": self.morph.n_components,
            "n_identity_components": 0 if self.identity is None else int(self.identity.basis.shape[1]),
            "explained_variance": round(self.morph.explained_ratio(), 6),
            "q_unit": self.q_unit,
            "m": self.m,
            "n": self.n,
            **self.meta,
        }

    def to_bytes(self) -> bytes:
        """The model as ``.npz`` bytes (no pickled objects)."""
        buf = io.BytesIO()
        np.savez(buf, **self._arrays())
        return buf.getvalue()

    def save(self, path: str | Path) -> None:
        """Write the model to one ``.npz`` file, atomically (temporary file, then rename)."""
        path = Path(path)
        tmp = path.with_name(f"{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")  # writers may race
        tmp.write_bytes(self.to_bytes())
        tmp.replace(path)

    def _arrays(self) -> dict[str, np.ndarray]:
        sizes = np.array([len(s.support_vectors) for s in self.svms], dtype=np.int64)
        header = {"version": FORMAT_VERSION, "impressions": list(self.impressions), "q_unit": self.q_unit,
                  "m": self.m, "n": self.n, "total_variance": self.morph.total_variance, "meta": self.meta}
        arrays = {} if self.identity is None else {
            "identity_basis": self.identity.basis,
            "identity_variances": self.identity.variances,
            "identity_cross": self.identity.cross,
            "identity_noise_var": np.array(self.identity.noise_var),
        }
        return arrays | {
            "header": np.array(json.dumps(header)),
            "neutral": self.morph.neutral,
            "mean": self.morph.mean,
            "basis": self.morph.basis,
            "variances": self.morph.variances,
            "face_sizes": self.morph.topology.face_sizes,
            "face_indices": self.morph.topology.face_indices,
            "fisher": self.fisher,
            "sv_counts": sizes,
            "support_vectors": np.concatenate([s.support_vectors for s in self.svms]),
            "sv_positive": np.concatenate([s.positive for s in self.svms]),
            "svm_coef": np.stack([s.coef for s in self.svms]),
            "svm_intercept": np.array([s.intercept for s in self.svms]),
        }


def load_face_model(source: str | Path | bytes) -> FaceModel:
    """Read a model written by :meth:`FaceModel.save` (a path or the ``.npz`` bytes).

    Raises FaceInputError when the file is not such a model.
    """
    try:
        data = np.load(io.BytesIO(source) if isinstance(source, bytes) else source, allow_pickle=False)
        header = json.loads(str(data["header"]))
        arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        raise FaceInputError(f"not a face model file: {exc}") from None
    if header.get("version") != FORMAT_VERSION:
        raise FaceInputError(f"unsupported face model version {header.get('version')!r}")
    topology = Mesh(arrays["neutral"], arrays["face_sizes"], arrays["face_indices"])
    morph = MorphableModel(arrays["neutral"], arrays["mean"], arrays["basis"], arrays["variances"],
                           float(header["total_variance"]), topology)
    bounds = np.concatenate([[0], np.cumsum(arrays["sv_counts"])])
    svms = tuple(
        SvmTransfer(arrays["support_vectors"][a:b], arrays["sv_positive"][a:b].astype(bool),
                    arrays["svm_coef"][i], float(arrays["svm_intercept"][i]))
        for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:]))
    )
    identity = None
    if "identity_basis" in arrays:
        identity = IdentityModel(arrays["identity_basis"], arrays["identity_variances"], arrays["identity_cross"],
                                 float(arrays["identity_noise_var"]))
    return FaceModel(morph, tuple(header["impressions"]), arrays["fisher"], svms, float(header["q_unit"]),
                     int(header["m"]), int(header["n"]), header.get("meta", {}), identity)
