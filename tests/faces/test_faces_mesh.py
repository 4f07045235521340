"""OBJ/PLY reading and writing with the topology kept, vertex replacement, and bad files."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from workers.faces.errors import FaceInputError
from workers.faces.mesh import (Mesh, check_finite, check_topology, detect_format, fan_triangulate, read_mesh,
                                replace_vertices, vertex_normals, write_mesh)

# A unit cube's corners; faces: a quad, two triangles and a pentagon-free mix of sizes.
CUBE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
SIZES = np.array([4, 3, 3, 4])
INDICES = np.array([0, 1, 2, 3, 4, 5, 6, 4, 6, 7, 0, 4, 7, 3])


def mixed_mesh() -> Mesh:
    return Mesh(CUBE + 0.125, SIZES, INDICES)


@pytest.mark.parametrize("fmt,binary", [("obj", False), ("ply", True), ("ply", False)])
def test_round_trip_keeps_topology_and_positions(fmt, binary):
    mesh = mixed_mesh()
    back = read_mesh(write_mesh(mesh, fmt, binary), f"x.{fmt}")
    assert back.same_topology(mesh)
    np.testing.assert_allclose(back.vertices, mesh.vertices, atol=1e-7)


def test_obj_texture_normal_refs_negative_indices_and_comments():
    text = "\n".join([
        "# comment", "mtllib a.mtl", "o thing",
        "v 0 0 0", "v 1 0 0", "v 1 1 0 0.5 0.5 0.5", "v 0 1 0",
        "vt 0 0", "vt 1 0", "vt 1 1", "vn 0 0 1",
        "usemtl skin", "f 1/1/1 2/2/1 3/3/1", "f -4//1 -2//1 -1//1", "f 1 3 4",
    ])
    mesh = read_mesh(text.encode(), "a.obj")
    assert mesh.n_vertices == 4
    assert mesh.face_sizes.tolist() == [3, 3, 3]
    assert mesh.face_indices.tolist() == [0, 1, 2, 0, 2, 3, 0, 2, 3]
    np.testing.assert_array_equal(mesh.vertices[2], [1, 1, 0])


def test_obj_replace_keeps_everything_but_positions_and_normals():
    text = ("mtllib a.mtl\nv 0 0 0\nv\t1 0 0\nv 0 1 0 0.2 0.3 0.4\nvt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\n"
            "f 1/1/1 2/2/1 3/3/1\n")
    new = np.array([[0, 0, 1.5], [2, 0, 0], [0, 3, 0]], float)
    out = replace_vertices(text.encode(), new, "a.obj").decode()
    assert "mtllib a.mtl" in out and "vt 0 1" in out
    assert "vn" not in out and "f 1/1 2/2 3/3" in out
    assert "v 0 3 0 0.2 0.3 0.4" in out  # vertex colour kept
    np.testing.assert_allclose(read_mesh(out.encode(), "a.obj").vertices, new)


def test_ply_binary_with_extra_properties_and_other_elements():
    """Big-endian, float vertices with normals and colours, an int face list, and an edge element."""
    verts = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)]
    header = (
        "ply\nformat binary_big_endian 1.0\ncomment test\n"
        "element vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
        "property float nx\nproperty float ny\nproperty float nz\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        "element face 2\nproperty list uchar int vertex_indices\n"
        "element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n"
    ).encode()
    body = b"".join(struct.pack(">6f3B", *v, 0, 0, -1, 10 * i, 20, 30) for i, v in enumerate(verts))
    body += struct.pack(">B3i", 3, 0, 1, 2) + struct.pack(">B3i", 3, 1, 3, 2) + struct.pack(">2i", 0, 3)
    data = header + body
    mesh = read_mesh(data, "scan.ply")
    assert mesh.face_indices.tolist() == [0, 1, 2, 1, 3, 2]
    new = mesh.vertices + [0, 0, 2]
    out = replace_vertices(data, new, "scan.ply")
    assert out[:len(header)] == header and out.endswith(struct.pack(">2i", 0, 3))
    np.testing.assert_allclose(read_mesh(out).vertices, new)
    record = np.frombuffer(out, dtype=np.dtype([("p", ">f4", 6), ("c", "u1", 3)]), count=4, offset=len(header))
    assert record["c"][:, 0].tolist() == [0, 10, 20, 30]  # colours untouched
    np.testing.assert_allclose(record["p"][:, 3:], [[0, 0, 1]] * 4, atol=1e-6)  # normals recomputed


def test_ply_binary_mixed_face_sizes_use_the_general_reader():
    data = write_mesh(mixed_mesh(), "ply", binary=True)
    back = read_mesh(data)
    assert back.face_sizes.tolist() == SIZES.tolist() and back.face_indices.tolist() == INDICES.tolist()


def test_ply_ascii_replace_vertices():
    mesh = Mesh.from_faces(CUBE[:4], [[0, 1, 2], [0, 2, 3]])
    data = write_mesh(mesh, "ply", binary=False)
    out = replace_vertices(data, mesh.vertices * 2, "a.ply")
    back = read_mesh(out)
    assert back.same_topology(mesh)
    np.testing.assert_allclose(back.vertices, mesh.vertices * 2)


def test_fan_triangulation_and_normals():
    tris = fan_triangulate(np.array([4, 3]), np.array([0, 1, 2, 3, 4, 5, 6]))
    assert tris.tolist() == [[0, 1, 2], [0, 2, 3], [4, 5, 6]]
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    np.testing.assert_allclose(vertex_normals(square, tris[:2]), [[0, 0, 1]] * 4)


@pytest.mark.parametrize("data,name,message", [
    (b"", "a.obj", "empty"),
    (bytes(range(256)) * 4, "a.obj", "binary data"),
    (b"hello world\nthis is text\n", "notes.obj", "no vertices"),
    (b"v 0 0 0\nv 1 0 0\n", "a.obj", "no faces"),
    (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 5\n", "a.obj", "does not exist"),
    (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "a.obj", "fewer than 3"),
    (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", "a.obj", "integers"),
    (b"v 0 0 zero\nf 1 1 1\n", "a.obj", "malformed"),
    (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n", "a.ply", "end_header"),
    (b"PK\x03\x04 a zip", "a.ply", "PLY magic"),
    (b"v 0 0 0\n", "a.stl", "use .obj or .ply"),
])
def test_bad_files_raise_a_clear_input_error(data, name, message):
    with pytest.raises(FaceInputError, match=message):
        read_mesh(data, name)


def test_truncated_binary_ply():
    data = write_mesh(Mesh.from_faces(CUBE[:3], [[0, 1, 2]]), "ply", binary=True)
    with pytest.raises(FaceInputError, match="truncated"):
        read_mesh(data[:-20])


def test_format_detection():
    assert detect_format(b"ply\nformat ascii 1.0\n", None) == "ply"
    assert detect_format(b"v 0 0 0\n", "A.OBJ") == "obj"
    assert detect_format(b"ply\n...", "obj") == "ply"  # the magic wins over a wrong name


def test_topology_and_nan_checks():
    ref = Mesh.from_faces(CUBE[:4], [[0, 1, 2], [0, 2, 3]])
    check_topology(ref.with_vertices(ref.vertices + 1), ref)
    with pytest.raises(FaceInputError, match="3 vertices but the model expects 4"):
        check_topology(Mesh.from_faces(CUBE[:3], [[0, 1, 2]]), ref)
    with pytest.raises(FaceInputError, match="different faces"):
        check_topology(Mesh.from_faces(CUBE[:4], [[0, 1, 3], [1, 2, 3]]), ref)
    bad = ref.vertices.copy()
    bad[2, 1] = np.nan
    with pytest.raises(FaceInputError, match="NaN.*vertex 2"):
        check_finite(ref.with_vertices(bad))


def test_parse_estimate_of_a_64_mib_upload():
    from workers.common.work import WorkEstimate
    from workers.faces.mesh import parse_estimate

    # 0.046 CPU-s per MiB and 12 bytes per byte (a 54 MiB OBJ measured 2.5 s and 635 MB)
    assert parse_estimate(64 * 2**20) == WorkEstimate(pytest.approx(2.944), 768 * 2**20)
