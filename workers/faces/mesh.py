"""Polygon meshes in OBJ and PLY (ASCII and binary), read and written with their topology kept.

A :class:`Mesh` holds vertex positions and polygons of any size (faces are stored flat, as in
PLY: ``face_sizes`` and the concatenated ``face_indices``). :func:`replace_vertices` rewrites
only the vertex positions of an uploaded file, so a transformed mesh keeps everything else the
user had in it (texture coordinates, groups, materials, colours, extra PLY elements).

Kept rather than a library (``python -m benchmarks.mesh_io``): on the hostile files of the tests trimesh
accepts 5 of 11 broken files (empty, no vertices, no faces, 2-corner faces) and cannot read a valid binary
PLY of mixed polygon sizes; meshio accepts 5 and hangs on 2 malformed PLY headers; plyfile (PLY only)
refuses every bad PLY and keeps the polygons, but reads 2.6x (binary) to 5.8x (ASCII) slower than this
module, and the OBJ half would stay ours anyway.
"""
from __future__ import annotations

import io
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from workers.common.work import WorkEstimate
from workers.faces.errors import FaceInputError

FORMATS = ("obj", "ply")
_PARSE_S_PER_MIB, _PARSE_BYTES_PER_BYTE = 0.046, 12
"""Parsing a text OBJ, the costlier format (a 54 MiB OBJ of 1.4 M vertices: 2.5 CPU-s, 635 MB peak, measured on
the reference machine): Python's lines and the token arrays take about 12 bytes per byte of the file."""


@dataclass(frozen=True, eq=False)
class Mesh:
    """A polygon mesh.

    ``vertices``: (N, 3) float64 positions; ``face_sizes``: (F,) int64 corner counts (>= 3);
    ``face_indices``: (sum(face_sizes),) int64 0-based vertex indices, faces concatenated.
    """

    vertices: np.ndarray
    face_sizes: np.ndarray
    face_indices: np.ndarray

    @classmethod
    def from_faces(cls, vertices: np.ndarray, faces: np.ndarray) -> "Mesh":
        """A mesh from (N, 3) positions and an (F, k) int array of polygons with k corners each."""
        faces = np.asarray(faces, dtype=np.int64)
        sizes = np.full(len(faces), faces.shape[1], dtype=np.int64)
        return cls(np.asarray(vertices, dtype=np.float64), sizes, faces.ravel())

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_faces(self) -> int:
        return len(self.face_sizes)

    def with_vertices(self, vertices: np.ndarray) -> "Mesh":
        """The same topology with new (N, 3) positions."""
        vertices = np.asarray(vertices, dtype=np.float64)
        if vertices.shape != self.vertices.shape:
            raise ValueError(f"expected vertices of shape {self.vertices.shape}, got {vertices.shape}")
        return Mesh(vertices, self.face_sizes, self.face_indices)

    def triangles(self) -> np.ndarray:
        """(T, 3) int64 triangles: each polygon fanned from its first corner."""
        return fan_triangulate(self.face_sizes, self.face_indices)

    def same_topology(self, other: "Mesh") -> bool:
        """True when both meshes have the same vertex count and the same polygons in the same order."""
        return (
            self.n_vertices == other.n_vertices
            and np.array_equal(self.face_sizes, other.face_sizes)
            and np.array_equal(self.face_indices, other.face_indices)
        )


def fan_triangulate(face_sizes: np.ndarray, face_indices: np.ndarray) -> np.ndarray:
    """(T, 3) int64 triangles fanning each polygon of (F,) sizes and flat (sum sizes,) indices."""
    sizes = np.asarray(face_sizes, dtype=np.int64)
    starts = np.cumsum(sizes) - sizes
    n_tri = sizes - 2
    face_of_tri = np.repeat(np.arange(len(sizes)), n_tri)
    corner = np.arange(n_tri.sum()) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri) + 1
    base = starts[face_of_tri]
    idx = np.asarray(face_indices, dtype=np.int64)
    return np.stack([idx[base], idx[base + corner], idx[base + corner + 1]], axis=1)


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(N, 3) float64 unit area-weighted vertex normals of (N, 3) positions and (T, 3) triangles."""
    v = np.asarray(vertices, dtype=np.float64)
    tri = v[triangles]
    face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    corners = np.asarray(triangles).ravel()
    weights = np.repeat(face_n, 3, axis=0)  # each triangle's normal once per corner
    normals = np.stack([np.bincount(corners, weights=weights[:, a], minlength=len(v)) for a in range(3)], axis=1)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return normals / np.where(length > 0, length, 1.0)


def check_finite(mesh: Mesh) -> None:
    """Raise :class:`FaceInputError` when a vertex coordinate is NaN or infinite."""
    bad = ~np.isfinite(mesh.vertices).all(axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise FaceInputError(
            f"the mesh has {int(bad.sum())} vertices with NaN or infinite coordinates (first: vertex {first})"
        )


def check_topology(mesh: Mesh, reference: Mesh, what: str = "the model") -> None:
    """Raise :class:`FaceInputError` unless ``mesh`` has the vertex count and faces of ``reference``."""
    if mesh.n_vertices != reference.n_vertices:
        raise FaceInputError(
            f"the mesh has {mesh.n_vertices} vertices but {what} expects {reference.n_vertices}: "
            "it must be registered to the model's topology"
        )
    if not (np.array_equal(mesh.face_sizes, reference.face_sizes)
            and np.array_equal(mesh.face_indices, reference.face_indices)):
        raise FaceInputError(
            f"the mesh has {mesh.n_vertices} vertices like {what} but different faces "
            f"({mesh.n_faces} faces, {what} has {reference.n_faces}): it must have the model's topology"
        )


def detect_format(data: bytes, name: str | None = None) -> str:
    """``"obj"`` or ``"ply"`` from the file's magic bytes and its name or a bare format name."""
    hint = _format_hint(name)
    if data[:3] == b"ply":
        return "ply"
    if hint == "ply":
        raise FaceInputError("the file is named .ply but does not start with the PLY magic 'ply'")
    return "obj"


def _format_hint(name: str | None) -> str | None:
    if not name:
        return None
    lowered = name.lower()
    if lowered in FORMATS:
        return lowered
    suffix = Path(lowered).suffix.lstrip(".")
    if suffix in FORMATS:
        return suffix
    raise FaceInputError(f"unsupported mesh file {name!r}: use .obj or .ply")


def read_mesh(data: bytes, name: str | None = None) -> Mesh:
    """Parse OBJ or PLY bytes (format from magic bytes and ``name``); raises FaceInputError."""
    if not data:
        raise FaceInputError("the mesh file is empty")
    fmt = detect_format(data, name)
    mesh = _read_ply(data) if fmt == "ply" else _read_obj(data)
    if mesh.n_faces == 0:
        raise FaceInputError("the file has vertices but no faces: a mesh with faces is needed")
    return mesh


def parse_estimate(mesh_bytes: int) -> WorkEstimate:
    """What :func:`read_mesh` costs on a file of ``mesh_bytes`` bytes: CPU seconds and peak memory (bytes), before
    the mesh is checked against a model's topology (an oversized upload costs that much to refuse)."""
    return WorkEstimate(_PARSE_S_PER_MIB * mesh_bytes / 2**20, _PARSE_BYTES_PER_BYTE * mesh_bytes)


def write_mesh(mesh: Mesh, fmt: str, binary: bool = True) -> bytes:
    """Serialise ``mesh`` as ``"obj"`` (text) or ``"ply"`` (binary little-endian, or ASCII)."""
    if fmt == "obj":
        return _write_obj(mesh)
    if fmt == "ply":
        return _write_ply(mesh, binary)
    raise ValueError(f"unknown mesh format {fmt!r}")


def replace_vertices(data: bytes, vertices: np.ndarray, name: str | None = None) -> bytes:
    """The uploaded file ``data`` with its vertex positions replaced by (N, 3) ``vertices``.

    Everything else is kept. Normals that the new positions make stale are handled: PLY
    ``nx ny nz`` are recomputed, OBJ ``vn`` lines are dropped (with their face references).
    """
    if detect_format(data, name) == "ply":
        return _replace_ply(data, np.asarray(vertices, dtype=np.float64))
    return _replace_obj(data, np.asarray(vertices, dtype=np.float64))


# ---------------------------------------------------------------------------------------- OBJ

def _decode_text(data: bytes) -> str:
    if b"\x00" in data[:4096]:
        raise FaceInputError("the file is binary data, not an OBJ or PLY mesh")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def _obj_lines(data: bytes) -> tuple[list[str], list[str]]:
    """The OBJ's lines (tabs as spaces) and each line's first two characters, e.g. ``"v "``."""
    lines = _decode_text(data).replace("\t", " ").splitlines()
    return lines, [line[:2] for line in lines]


def _tokens_per_line(block: str) -> np.ndarray:
    """(L,) int64 count of space-separated tokens on each line of ``block``, without a Python loop."""
    b = np.frombuffer(block.encode("utf-8"), dtype=np.uint8)
    gap = (b == 32) | (b == 10) | (b == 13)
    starts = ~gap & np.concatenate([[True], gap[:-1]])
    line_of = np.cumsum(b == 10)
    return np.bincount(line_of[starts], minlength=block.count("\n") + 1).astype(np.int64)


def _read_obj(data: bytes) -> Mesh:
    lines, kinds = _obj_lines(data)
    v_pos = [i for i, k in enumerate(kinds) if k == "v "]
    f_pos = [i for i, k in enumerate(kinds) if k == "f "]
    if not v_pos:
        raise FaceInputError("no vertices ('v' lines) found: the file is not an OBJ mesh")
    try:
        vertices = np.loadtxt(io.StringIO("\n".join([lines[i] for i in v_pos])), usecols=(1, 2, 3), ndmin=2)
    except ValueError as exc:
        raise FaceInputError(f"malformed OBJ vertex line: {exc}") from None
    block = re.sub(r"/\S*", "", "\n".join([lines[i][2:] for i in f_pos]))
    sizes = _tokens_per_line(block) if f_pos else np.zeros(0, np.int64)
    flat = _parse_ints(block, int(sizes.sum()))
    if (sizes < 3).any():
        raise FaceInputError(f"OBJ face line {f_pos[int(np.argmax(sizes < 3))] + 1} has fewer than 3 corners")
    indices = _obj_indices(flat, sizes, np.asarray(v_pos), np.asarray(f_pos))
    if indices.size and (indices.min() < 0 or indices.max() >= len(vertices)):
        raise FaceInputError(f"an OBJ face refers to a vertex that does not exist (the file has {len(vertices)})")
    return Mesh(vertices.astype(np.float64), sizes, indices)


def _parse_ints(block: str, count: int) -> np.ndarray:
    """(count,) int64 from whitespace-separated integers (numpy's C parser; 10x faster than split)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # numpy warns, not raises, on bad text
        try:
            values = np.fromstring(block, dtype=np.int64, sep=" ")
        except (ValueError, DeprecationWarning):
            values = None
    if values is None or values.size != count:
        raise FaceInputError("malformed OBJ face line: indices must be integers")
    return values


def _obj_indices(flat: np.ndarray, sizes: np.ndarray, v_pos: np.ndarray, f_pos: np.ndarray) -> np.ndarray:
    """0-based indices from OBJ's 1-based ones; negative ones count back from the vertices so far."""
    if (flat == 0).any():
        raise FaceInputError("an OBJ face uses vertex index 0 (OBJ indices start at 1)")
    indices = flat - 1
    negative = flat < 0
    if negative.any():
        seen = np.searchsorted(v_pos, f_pos)
        indices[negative] = np.repeat(seen, sizes)[negative] + flat[negative]
    return indices


def _format_rows(values: np.ndarray, fmt: str) -> str:
    """Rows of a 2-D array formatted with one printf line format, in one C-level operation."""
    return (fmt * len(values)) % tuple(values.ravel().tolist()) if len(values) else ""


def _write_obj(mesh: Mesh) -> bytes:
    parts = [_format_rows(mesh.vertices, "v %.8g %.8g %.8g\n")]
    sizes = mesh.face_sizes
    starts = np.cumsum(sizes) - sizes
    parts.append(_format_faces_obj(mesh.face_indices + 1, sizes, starts))
    return "".join(parts).encode("ascii")


def _format_faces_obj(one_based: np.ndarray, sizes: np.ndarray, starts: np.ndarray) -> str:
    if len(sizes) and (sizes == sizes[0]).all():
        k = int(sizes[0])
        return _format_rows(one_based.reshape(-1, k), "f" + " %d" * k + "\n")
    return "".join(
        "f " + " ".join(map(str, one_based[s:s + k].tolist())) + "\n" for s, k in zip(starts, sizes)
    )


def _replace_obj(data: bytes, vertices: np.ndarray) -> bytes:
    newline = "\r\n" if b"\r\n" in data else "\n"
    lines, kinds = _obj_lines(data)
    v_pos = [i for i, k in enumerate(kinds) if k == "v "]
    if len(v_pos) != len(vertices):
        raise FaceInputError(f"the OBJ has {len(v_pos)} vertices, {len(vertices)} were given")
    new_v = _format_rows(vertices, "v %.8g %.8g %.8g\n").split("\n")
    extra = np.flatnonzero(_tokens_per_line("\n".join([lines[i] for i in v_pos])) > 4)
    for row in extra.tolist():  # keep what follows x y z (vertex colours)
        new_v[row] += " " + " ".join(lines[v_pos[row]].split()[4:])
    for row, i in enumerate(v_pos):
        lines[i] = new_v[row]
    if "vn" in set(kinds):
        lines = [_drop_normal_refs(line) for line, k in zip(lines, kinds) if k != "vn"]
    return (newline.join(lines) + newline).encode("utf-8")


def _drop_normal_refs(line: str) -> str:
    """An OBJ face line without its normal references (``a/b/c`` -> ``a/b``, ``a//c`` -> ``a``)."""
    if not line.startswith(("f ", "f\t")):
        return line
    corners = []
    for token in line.split()[1:]:
        parts = token.split("/")
        corners.append(parts[0] + ("/" + parts[1] if len(parts) > 1 and parts[1] else ""))
    return "f " + " ".join(corners)


# ---------------------------------------------------------------------------------------- PLY

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_FACE_LISTS = ("vertex_indices", "vertex_index")


@dataclass
class _PlyProperty:
    name: str
    dtype: str  # numpy type code without byte order, e.g. "f4"
    count_dtype: str | None = None  # set for list properties


@dataclass
class _PlyElement:
    name: str
    count: int
    properties: list[_PlyProperty]
    start: int = 0  # byte offset (binary) or line index (ASCII) of the first item
    end: int = 0

    @property
    def has_lists(self) -> bool:
        return any(p.count_dtype for p in self.properties)


@dataclass
class _PlyFile:
    encoding: str  # "ascii", "<" or ">"
    header_end: int
    elements: list[_PlyElement]

    def element(self, name: str) -> _PlyElement | None:
        return next((e for e in self.elements if e.name == name), None)


def _parse_ply_header(data: bytes) -> _PlyFile:
    match = re.search(rb"end_header[ \t]*\r?\n", data[:65536])
    if not match:
        raise FaceInputError("the PLY header has no 'end_header' line")
    header = data[:match.start()].decode("ascii", errors="replace").splitlines()
    encoding, elements = None, []
    for line in header[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            encoding = {"ascii": "ascii", "binary_little_endian": "<", "binary_big_endian": ">"}.get(words[1])
        elif words[0] == "element" and len(words) == 3:
            elements.append(_PlyElement(words[1], _ply_int(words[2]), []))
        elif words[0] == "property" and elements:
            elements[-1].properties.append(_ply_property(words))
        else:
            raise FaceInputError(f"unexpected PLY header line: {line!r}")
    if encoding is None:
        raise FaceInputError("the PLY header has no valid 'format' line")
    return _PlyFile(encoding, match.end(), elements)


def _ply_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise FaceInputError(f"bad PLY element count {text!r}") from None
    if value < 0:
        raise FaceInputError(f"bad PLY element count {text!r}")
    return value


def _ply_property(words: list[str]) -> _PlyProperty:
    try:
        if words[1] == "list":
            return _PlyProperty(words[4], _PLY_TYPES[words[3]], _PLY_TYPES[words[2]])
        return _PlyProperty(words[2], _PLY_TYPES[words[1]])
    except (KeyError, IndexError):
        raise FaceInputError(f"bad PLY property line: {' '.join(words)!r}") from None


def _read_ply(data: bytes) -> Mesh:
    ply = _parse_ply_header(data)
    columns = _ply_read_body(data, ply)
    vertex = ply.element("vertex")
    if vertex is None or not all(a in columns.get("vertex", {}) for a in "xyz"):
        raise FaceInputError("the PLY file has no vertex element with x, y, z")
    v = columns["vertex"]
    vertices = np.stack([np.asarray(v[a], dtype=np.float64) for a in "xyz"], axis=1)
    sizes, indices = np.zeros(0, np.int64), np.zeros(0, np.int64)
    face = columns.get("face", {})
    key = next((k for k in _FACE_LISTS if k in face), None)
    if key is not None:
        sizes, indices = face[key]
    if (sizes < 3).any():
        raise FaceInputError("a PLY face has fewer than 3 corners")
    if indices.size and (indices.min() < 0 or indices.max() >= len(vertices)):
        raise FaceInputError(f"a PLY face refers to a vertex that does not exist (the file has {len(vertices)})")
    return Mesh(vertices, sizes, indices)


def _ply_read_body(data: bytes, ply: _PlyFile) -> dict[str, dict[str, object]]:
    """Element name -> property name -> (count,) array, or (sizes, flat) for list properties."""
    if ply.encoding == "ascii":
        return _ply_read_ascii(data, ply)
    out: dict[str, dict[str, object]] = {}
    offset = ply.header_end
    for element in ply.elements:
        element.start = offset
        if element.has_lists:
            out[element.name], offset = _ply_binary_lists(data, offset, element, ply.encoding)
        else:
            dtype = _ply_record_dtype(element, ply.encoding)
            arr = _frombuffer(data, dtype, element.count, offset)
            out[element.name] = {p.name: arr[p.name] for p in element.properties}
            offset += element.count * dtype.itemsize
        element.end = offset
    return out


def _ply_record_dtype(element: _PlyElement, order: str) -> np.dtype:
    return np.dtype([(p.name, order + p.dtype) for p in element.properties])


def _frombuffer(data: bytes, dtype: np.dtype, count: int, offset: int) -> np.ndarray:
    if offset + count * dtype.itemsize > len(data):
        raise FaceInputError("the PLY file is truncated: its body is shorter than its header says")
    return np.frombuffer(data, dtype=dtype, count=count, offset=offset)


def _ply_binary_lists(data: bytes, offset: int, element: _PlyElement, order: str):
    """Read an element with list properties: fast when every list has the first one's length."""
    if element.count == 0:
        return {}, offset
    fields, pos = [], offset
    for p in element.properties:
        if p.count_dtype:
            n = int(_frombuffer(data, np.dtype(order + p.count_dtype), 1, pos)[0])
            fields += [(p.name + "#n", order + p.count_dtype), (p.name, order + p.dtype, (n,))]
            pos += np.dtype(order + p.count_dtype).itemsize + n * np.dtype(p.dtype).itemsize
        else:
            fields.append((p.name, order + p.dtype))
            pos += np.dtype(p.dtype).itemsize
    dtype = np.dtype(fields)
    if offset + element.count * dtype.itemsize <= len(data):
        arr = np.frombuffer(data, dtype=dtype, count=element.count, offset=offset)
        lists = [p for p in element.properties if p.count_dtype]
        if all((arr[p.name + "#n"] == arr.dtype[p.name].shape[0]).all() for p in lists):
            return _ply_uniform_columns(arr, element), offset + element.count * dtype.itemsize
    return _ply_binary_lists_slow(data, offset, element, order)


def _ply_uniform_columns(arr: np.ndarray, element: _PlyElement) -> dict[str, object]:
    out: dict[str, object] = {}
    for p in element.properties:
        if p.count_dtype:
            items = np.asarray(arr[p.name], dtype=np.int64)
            out[p.name] = (np.full(len(arr), items.shape[1], dtype=np.int64), items.ravel())
        else:
            out[p.name] = arr[p.name]
    return out


def _ply_binary_lists_slow(data: bytes, offset: int, element: _PlyElement, order: str):
    scalars: dict[str, list] = {p.name: [] for p in element.properties if not p.count_dtype}
    lists: dict[str, tuple[list, list]] = {p.name: ([], []) for p in element.properties if p.count_dtype}
    for _ in range(element.count):
        for p in element.properties:
            if p.count_dtype:
                n = int(_frombuffer(data, np.dtype(order + p.count_dtype), 1, offset)[0])
                offset += np.dtype(p.count_dtype).itemsize
                lists[p.name][0].append(n)
                lists[p.name][1].append(_frombuffer(data, np.dtype(order + p.dtype), n, offset))
                offset += n * np.dtype(p.dtype).itemsize
            else:
                scalars[p.name].append(_frombuffer(data, np.dtype(order + p.dtype), 1, offset)[0])
                offset += np.dtype(p.dtype).itemsize
    out: dict[str, object] = {k: np.asarray(v) for k, v in scalars.items()}
    for name, (sizes, chunks) in lists.items():
        flat = np.concatenate(chunks).astype(np.int64) if chunks else np.zeros(0, np.int64)
        out[name] = (np.asarray(sizes, dtype=np.int64), flat)
    return out, offset


def _ply_ascii_lines(data: bytes, ply: _PlyFile) -> list[str]:
    body = data[ply.header_end:].decode("ascii", errors="replace")
    return [line for line in body.splitlines() if line.strip()]


def _ply_read_ascii(data: bytes, ply: _PlyFile) -> dict[str, dict[str, object]]:
    lines = _ply_ascii_lines(data, ply)
    out: dict[str, dict[str, object]] = {}
    row = 0
    for element in ply.elements:
        element.start, element.end = row, row + element.count
        if element.end > len(lines):
            raise FaceInputError("the PLY file is truncated: fewer lines than its header says")
        chunk = lines[element.start:element.end]
        out[element.name] = _ply_ascii_element(chunk, element)
        row = element.end
    return out


def _ply_ascii_element(chunk: list[str], element: _PlyElement) -> dict[str, object]:
    if not element.has_lists:
        table = _ply_ascii_table(chunk, len(element.properties))
        return {p.name: table[:, i] for i, p in enumerate(element.properties)}
    rows = [line.split() for line in chunk]
    scalars: dict[str, list] = {p.name: [] for p in element.properties if not p.count_dtype}
    lists: dict[str, tuple[list, list]] = {p.name: ([], []) for p in element.properties if p.count_dtype}
    try:
        for tokens in rows:
            pos = 0
            for p in element.properties:
                if p.count_dtype:
                    n = int(tokens[pos])
                    lists[p.name][0].append(n)
                    lists[p.name][1].extend(tokens[pos + 1:pos + 1 + n])
                    pos += 1 + n
                else:
                    scalars[p.name].append(float(tokens[pos]))
                    pos += 1
        out: dict[str, object] = {k: np.asarray(v) for k, v in scalars.items()}
        for name, (sizes, flat) in lists.items():
            out[name] = (np.asarray(sizes, dtype=np.int64), np.array(flat, dtype=np.int64))
    except (ValueError, IndexError):
        raise FaceInputError(f"malformed PLY '{element.name}' line in the ASCII body") from None
    return out


def _ply_ascii_table(chunk: list[str], n_props: int) -> np.ndarray:
    if not chunk:
        return np.zeros((0, n_props))
    try:
        return np.loadtxt(io.StringIO("\n".join(chunk)), ndmin=2, usecols=range(n_props))
    except ValueError as exc:
        raise FaceInputError(f"malformed PLY ASCII line: {exc}") from None


def _write_ply(mesh: Mesh, binary: bool) -> bytes:
    head = [
        "ply",
        f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
        f"element vertex {mesh.n_vertices}",
        "property double x", "property double y", "property double z",
        f"element face {mesh.n_faces}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    if np.any(mesh.face_sizes > 255):
        raise ValueError("PLY faces with more than 255 corners are not supported")
    header = ("\n".join(head) + "\n").encode("ascii")
    if not binary:
        verts = _format_rows(mesh.vertices, "%.17g %.17g %.17g\n")
        starts = np.cumsum(mesh.face_sizes) - mesh.face_sizes
        faces = "".join(
            f"{k} " + " ".join(map(str, mesh.face_indices[s:s + k].tolist())) + "\n"
            for s, k in zip(starts.tolist(), mesh.face_sizes.tolist())
        )
        return header + (verts + faces).encode("ascii")
    return header + mesh.vertices.astype("<f8").tobytes() + _ply_binary_faces(mesh)


def _ply_binary_faces(mesh: Mesh) -> bytes:
    """Interleave uchar counts and int32 indices without a Python loop over faces."""
    sizes = mesh.face_sizes
    record = 1 + 4 * sizes
    starts = np.cumsum(record) - record
    out = np.zeros(int(record.sum()), dtype=np.uint8)
    out[starts] = sizes.astype(np.uint8)
    corner_start = np.cumsum(sizes) - sizes
    corner = np.arange(len(mesh.face_indices)) - np.repeat(corner_start, sizes)
    first_byte = np.repeat(starts + 1, sizes) + 4 * corner
    index_bytes = mesh.face_indices.astype("<i4").view(np.uint8).reshape(-1, 4)
    out[first_byte[:, None] + np.arange(4)] = index_bytes
    return out.tobytes()


def _replace_ply(data: bytes, vertices: np.ndarray) -> bytes:
    mesh = _read_ply(data)
    ply = _parse_ply_header(data)
    _ply_read_body(data, ply)  # fills element offsets
    vertex = ply.element("vertex")
    if vertex.has_lists:
        raise FaceInputError("PLY vertex elements with list properties are not supported")
    if len(vertices) != vertex.count:
        raise FaceInputError(f"the PLY has {vertex.count} vertices, {len(vertices)} were given")
    names = [p.name for p in vertex.properties]
    new_cols = {"x": vertices[:, 0], "y": vertices[:, 1], "z": vertices[:, 2]}
    if all(a in names for a in ("nx", "ny", "nz")):
        normals = vertex_normals(vertices, mesh.triangles())
        new_cols.update(nx=normals[:, 0], ny=normals[:, 1], nz=normals[:, 2])
    if ply.encoding == "ascii":
        return _replace_ply_ascii(data, ply, vertex, new_cols)
    arr = np.frombuffer(data, dtype=_ply_record_dtype(vertex, ply.encoding), count=vertex.count,
                        offset=vertex.start).copy()
    for name, values in new_cols.items():
        arr[name] = values
    return data[:vertex.start] + arr.tobytes() + data[vertex.end:]


def _replace_ply_ascii(data: bytes, ply: _PlyFile, vertex: _PlyElement, new_cols: dict) -> bytes:
    lines = _ply_ascii_lines(data, ply)
    table = _ply_ascii_table(lines[vertex.start:vertex.end], len(vertex.properties))
    fmts = []
    for i, p in enumerate(vertex.properties):
        if p.name in new_cols:
            table[:, i] = new_cols[p.name]
        fmts.append({"f4": "%.9g", "f8": "%.17g"}.get(p.dtype, "%d"))
    rows = _format_rows(table, " ".join(fmts) + "\n").splitlines()
    lines[vertex.start:vertex.end] = rows
    return data[:ply.header_end] + ("\n".join(lines) + "\n").encode("ascii")
