"""Training sets of registered faces: the in-memory form and a user's zip with a CSV manifest.

A zip holds one CSV manifest (``manifest.csv``, or the only ``.csv`` in it) with the columns
``person,expression,file`` and the mesh files it names (OBJ or PLY, paths relative to the
manifest). Every mesh must share one topology (registered to one template), and every person
needs exactly one ``neutral`` face: the displacements of eq. 1 are taken from it.
"""
from __future__ import annotations

import csv
import io
import posixpath
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Callable

import numpy as np

from workers.common.safezip import SafeZip, ZipLimits
from workers.faces.errors import DatasetError, FaceInputError
from workers.faces.mesh import Mesh, check_finite, read_mesh, write_mesh

NEUTRAL = "neutral"
MAX_MESHES = 20000
_LABEL = re.compile(r"^[a-z][a-z0-9_]{0,39}$")


@dataclass(frozen=True, eq=False)
class FaceDataset:
    """Registered faces: ``vertices`` (M, N, 3) float64; ``persons`` and ``expressions`` (M,) str;
    ``topology``: the shared faces (a Mesh whose vertices are the first face's).

    Construction validates: one topology, finite coordinates, lower-case expression labels,
    exactly one ``neutral`` per person, at least two people and two faces per impression.
    """

    vertices: np.ndarray
    persons: np.ndarray
    expressions: np.ndarray
    topology: Mesh

    def __post_init__(self) -> None:
        _validate(self)

    @property
    def impressions(self) -> tuple[str, ...]:
        """The non-neutral expression labels, in order of first appearance."""
        labels = [e for e in dict.fromkeys(self.expressions.tolist()) if e != NEUTRAL]
        return tuple(labels)

    def neutral_index(self) -> np.ndarray:
        """(M,) int: for each face, the row of its person's neutral face."""
        rows = {p: i for i, (p, e) in enumerate(zip(self.persons, self.expressions)) if e == NEUTRAL}
        return np.array([rows[p] for p in self.persons], dtype=np.int64)

    def displacements(self) -> np.ndarray:
        """Eq. 1, ``S_m = X_m - X_neutral`` of the same person: (M, 3N) float64 (neutral rows are 0)."""
        return (self.vertices - self.vertices[self.neutral_index()]).reshape(len(self.vertices), -1)

    def subset(self, persons: set[str] | list[str]) -> "FaceDataset":
        """The faces of the given people only."""
        keep = np.isin(self.persons, list(persons))
        return FaceDataset(self.vertices[keep], self.persons[keep], self.expressions[keep], self.topology)


def _validate(ds: FaceDataset) -> None:
    m = len(ds.vertices)
    if ds.vertices.ndim != 3 or ds.vertices.shape[2] != 3 or len(ds.persons) != m or len(ds.expressions) != m:
        raise FaceInputError("a dataset needs (M, N, 3) vertices with one person and one expression per face")
    if ds.vertices.shape[1] != ds.topology.n_vertices:
        raise FaceInputError("the faces and the topology have different vertex counts")
    if not np.isfinite(ds.vertices).all():
        raise FaceInputError("the dataset has NaN or infinite vertex coordinates")
    bad = sorted({e for e in ds.expressions.tolist() if not _LABEL.match(e)})
    if bad:
        raise FaceInputError(f"expression labels must be lower-case words like 'smile_open'; got {bad[:5]}")
    people = list(dict.fromkeys(ds.persons.tolist()))
    neutrals = ds.persons[ds.expressions == NEUTRAL].tolist()
    missing = [p for p in people if neutrals.count(p) != 1]
    if missing:
        raise FaceInputError(f"every person needs exactly one '{NEUTRAL}' face; check {missing[:5]}")
    if len(people) < 2:
        raise FaceInputError("the dataset needs at least two people")
    impressions = [e for e in dict.fromkeys(ds.expressions.tolist()) if e != NEUTRAL]
    if not impressions:
        raise FaceInputError("the dataset has only neutral faces: add faces with expressions")
    thin = [e for e in impressions if np.sum(ds.expressions == e) < 2]
    if thin:
        raise FaceInputError(f"each expression needs faces of at least two people; too few for {thin}")


def check_dataset_zip(source: BinaryIO, limits: ZipLimits, label: str = "the dataset zip") -> None:
    """Refuse at once, before a training job is made, a dataset that is no readable zip or breaks the zip
    ``limits`` (:class:`DatasetError` naming ``label``): the central directory is read, the members are not (the job
    reads them). ``source``: an open binary file, left at its start."""
    try:
        with SafeZip(source, limits, label, DatasetError):
            pass
    finally:
        source.seek(0)


def load_dataset_zip(
    source: bytes | str | Path, progress: Callable[[float, str], None] | None = None
) -> FaceDataset:
    """Read a zip of registered meshes with a ``person,expression,file`` CSV manifest.

    ``source``: the zip's bytes or a path. The archive is read through :class:`SafeZip` (member
    count, sizes, compression ratio and names checked; limits from the environment, i.e. the
    service's settings). Raises FaceInputError with the offending file named.
    """
    with SafeZip(source, label="the dataset zip", error=DatasetError) as archive:
        infos = {i.filename: i for i in archive.members}
        manifest = _find_manifest(infos)
        rows = _read_manifest(archive.read(manifest).decode("utf-8-sig", errors="replace"))
        base = posixpath.dirname(manifest)
        meshes = []
        for i, (person, expression, name) in enumerate(rows):
            meshes.append(_read_member(archive, infos, base, name))
            if progress and i % 20 == 0:
                progress(i / len(rows), f"reading meshes {i}/{len(rows)}")
    topology = meshes[0]
    for (_, _, name), mesh in zip(rows, meshes):
        if not mesh.same_topology(topology):
            raise FaceInputError(
                f"{name}: its topology ({mesh.n_vertices} vertices, {mesh.n_faces} faces) differs from "
                f"{rows[0][2]} ({topology.n_vertices} vertices, {topology.n_faces} faces); "
                "all meshes must be registered to one template"
            )
    return FaceDataset(
        np.stack([m.vertices for m in meshes]),
        np.array([r[0] for r in rows]),
        np.array([r[1] for r in rows]),
        topology,
    )


def _find_manifest(infos: dict[str, zipfile.ZipInfo]) -> str:
    named = [n for n in infos if posixpath.basename(n).lower() == "manifest.csv"]
    csvs = named or [n for n in infos if n.lower().endswith(".csv") and not n.startswith("__MACOSX/")]
    if len(csvs) != 1:
        raise FaceInputError(
            "the zip needs one CSV manifest (manifest.csv) with columns person,expression,file; "
            f"found {len(csvs)} CSV files"
        )
    return csvs[0]


def _read_manifest(text: str) -> list[tuple[str, str, str]]:
    reader = csv.DictReader(io.StringIO(text))
    fields = [f.strip().lower() for f in (reader.fieldnames or [])]
    if not {"person", "expression", "file"} <= set(fields):
        raise FaceInputError(f"the manifest needs the columns person,expression,file; it has {fields}")
    reader.fieldnames = fields
    rows = []
    for line, row in enumerate(reader, start=2):
        person, expression, name = (str(row.get(k) or "").strip() for k in ("person", "expression", "file"))
        if not (person and expression and name):
            raise FaceInputError(f"manifest line {line}: person, expression and file must all be given")
        rows.append((person, expression.lower(), name))
    if not rows:
        raise FaceInputError("the manifest lists no meshes")
    if len(rows) > MAX_MESHES:
        raise FaceInputError(f"the manifest lists {len(rows)} meshes; at most {MAX_MESHES} are accepted")
    seen = {}
    for person, expression, name in rows:
        if (person, expression) in seen:
            raise FaceInputError(f"{name}: person {person!r} has expression {expression!r} twice")
        seen[(person, expression)] = name
    return rows


def _read_member(archive: SafeZip, infos: dict, base: str, name: str) -> Mesh:
    path = posixpath.normpath(posixpath.join(base, name.replace("\\", "/")))
    if path not in infos:
        raise FaceInputError(f"the manifest names {name!r}, which is not in the zip")
    try:
        mesh = read_mesh(archive.read(path), path)
        check_finite(mesh)
    except FaceInputError as exc:
        raise FaceInputError(f"{name}: {exc}") from None
    return mesh


def write_dataset_zip(dataset: FaceDataset, fmt: str = "obj") -> bytes:
    """A zip in the importer's layout: ``manifest.csv`` and ``meshes/<row>_<expression>.<fmt>``."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        manifest = io.StringIO()
        writer = csv.writer(manifest, lineterminator="\n")
        writer.writerow(["person", "expression", "file"])
        for i, (vertices, person, expression) in enumerate(zip(dataset.vertices, dataset.persons,
                                                               dataset.expressions)):
            name = f"meshes/{i:05d}_{expression}.{fmt}"
            archive.writestr(name, write_mesh(dataset.topology.with_vertices(vertices), fmt))
            writer.writerow([person, expression, name])
        archive.writestr("manifest.csv", manifest.getvalue())
    return buf.getvalue()
