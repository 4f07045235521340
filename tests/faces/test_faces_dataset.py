"""The synthetic generator and the zip importer (manifest person,expression,file)."""
from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest

from workers.faces.dataset import FaceDataset, load_dataset_zip, write_dataset_zip
from workers.faces.errors import FaceInputError
from workers.faces.mesh import Mesh, write_mesh
from workers.faces.synthetic import EXPRESSIONS, generate_dataset


def test_generator_follows_the_papers_design():
    ds = generate_dataset(people=3, seed=1)
    assert ds.vertices.shape[0] == 3 * 7 and 2000 < ds.vertices.shape[1] < 10000
    assert ds.impressions == EXPRESSIONS
    assert sorted(set(ds.persons.tolist())) == ["p000", "p001", "p002"]
    disp = ds.displacements().reshape(len(ds.vertices), -1, 3)
    assert np.all(disp[ds.expressions == "neutral"] == 0)
    # Every expression moves part of the face by millimetres to centimetres, far above the noise;
    # identities differ by more than the noise too.
    assert np.all(np.abs(disp[ds.expressions != "neutral"]).max(axis=(1, 2)) > 0.4)
    neutrals = ds.vertices[ds.expressions == "neutral"]
    assert np.abs(neutrals[0] - neutrals[1]).max() > 0.5
    np.testing.assert_array_equal(generate_dataset(people=3, seed=1).vertices, ds.vertices)  # seeded


@pytest.mark.parametrize("fmt", ["obj", "ply"])
def test_zip_round_trip(fmt):
    ds = generate_dataset(people=2, seed=2)
    back = load_dataset_zip(write_dataset_zip(ds, fmt))
    assert back.persons.tolist() == ds.persons.tolist() and back.expressions.tolist() == ds.expressions.tolist()
    assert back.topology.same_topology(ds.topology)
    np.testing.assert_allclose(back.vertices, ds.vertices, atol=1e-5)


def _zip(files: dict[str, bytes | str]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for name, data in files.items():
            z.writestr(name, data)
    return buf.getvalue()


TRI = Mesh.from_faces(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float), [[0, 1, 2], [1, 3, 2]])


def _obj(shift: float = 0.0, mesh: Mesh = TRI) -> bytes:
    return write_mesh(mesh.with_vertices(mesh.vertices + shift), "obj")


def test_manifest_in_a_folder_with_relative_paths_and_extra_columns():
    manifest = ("Person,Expression,File,notes\na,neutral,m/a0.obj,x\na,Smile,m/a1.obj,\n"
                "b,neutral,m/b0.obj,\nb,smile,m/b1.obj,\n")
    data = _zip({"set/manifest.csv": manifest, "set/m/a0.obj": _obj(), "set/m/a1.obj": _obj(0.1),
                 "set/m/b0.obj": _obj(0.2), "set/m/b1.obj": _obj(0.4)})
    ds = load_dataset_zip(data)
    assert ds.impressions == ("smile",)
    np.testing.assert_allclose(ds.displacements()[[1, 3]], 0.1 * np.ones((2, 12)) * [[1], [2]])


@pytest.mark.parametrize("files,message", [
    ({"a.obj": "v 0 0 0"}, "one CSV manifest"),
    ({"manifest.csv": "who,what\n"}, "columns person,expression,file"),
    ({"manifest.csv": "person,expression,file\n"}, "lists no meshes"),
    ({"manifest.csv": "person,expression,file\na,neutral,\n"}, "line 2"),
    ({"manifest.csv": "person,expression,file\na,neutral,gone.obj\n"}, "'gone.obj', which is not in the zip"),
    ({"manifest.csv": "person,expression,file\na,neutral,x.obj\n", "x.obj": b"\x00\x01garbage"},
     "x.obj: the file is binary data"),
    ({"manifest.csv": "person,expression,file\na,neutral,x.obj\na,neutral,y.obj\n"}, "twice"),
])
def test_bad_zips(files, message):
    with pytest.raises(FaceInputError, match=message):
        load_dataset_zip(_zip(files))


def test_not_a_zip():
    with pytest.raises(FaceInputError, match="not a zip"):
        load_dataset_zip(b"hello")


def test_topology_mismatch_names_the_file():
    other = Mesh.from_faces(TRI.vertices[:3], [[0, 1, 2]])
    manifest = "person,expression,file\na,neutral,a0.obj\na,smile,a1.obj\n"
    with pytest.raises(FaceInputError, match="a1.obj: its topology"):
        load_dataset_zip(_zip({"manifest.csv": manifest, "a0.obj": _obj(), "a1.obj": _obj(0, other)}))


@pytest.mark.parametrize("persons,expressions,message", [
    (["a", "a", "b"], ["neutral", "smile", "smile"], "exactly one 'neutral'.*'b'"),
    (["a", "a"], ["neutral", "smile"], "at least two people"),
    (["a", "b"], ["neutral", "neutral"], "only neutral"),
    (["a", "a", "b"], ["neutral", "smile", "neutral"], "at least two people; too few for"),
    (["a", "a", "b", "b"], ["neutral", "Big Smile", "neutral", "x"], "lower-case"),
])
def test_dataset_rules(persons, expressions, message):
    vertices = np.repeat(TRI.vertices[None], len(persons), axis=0)
    with pytest.raises(FaceInputError, match=message):
        FaceDataset(vertices, np.array(persons), np.array(expressions), TRI)


def test_nan_in_a_dataset_mesh():
    manifest = "person,expression,file\na,neutral,a0.obj\n"
    with pytest.raises(FaceInputError, match="a0.obj: .*NaN"):
        load_dataset_zip(_zip({"manifest.csv": manifest, "a0.obj": _obj().replace(b"v 1 0 0", b"v nan 0 0")}))
