"""Our OBJ/PLY reader (workers/faces/mesh.py) against the maintained libraries: trimesh, meshio, plyfile.

Three questions decide whether ours can go: (1) does the library refuse each hostile file of
tests/faces/test_faces_mesh.py with an error (ours: FaceInputError naming the problem), or accept it;
(2) does it keep what the engine needs: the polygons exactly as uploaded (mixed sizes, file order, no
triangulation or vertex merging), extra PLY properties and elements, and OBJ texture references for
``replace_vertices``; (3) speed on a face-sized mesh (10,201 vertices, 10,000 quads and triangles mixed).

    python -m benchmarks.mesh_io        (the bench extra's trimesh and meshio; plyfile, GPL-3.0, only when
                                         installed by hand: `pip install plyfile`, else its column says so)
"""
from __future__ import annotations

import argparse
import io
import multiprocessing
import tempfile
import warnings
from pathlib import Path
from typing import Callable

import numpy as np

from benchmarks._report import md_table, prog, publish
from benchmarks._timing import load, timed
from workers.faces.errors import FaceInputError
from workers.faces.mesh import Mesh, read_mesh, write_mesh

CUBE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
TRUNCATED = write_mesh(Mesh.from_faces(CUBE[:3], [[0, 1, 2]]), "ply", binary=True)[:-20]
HOSTILE = [  # (what, bytes, name): the cases of tests/faces/test_faces_mesh.py
    ("empty file", b"", "a.obj"),
    ("binary junk as OBJ", bytes(range(256)) * 4, "a.obj"),
    ("text without vertices", b"hello world\nthis is text\n", "notes.obj"),
    ("vertices, no faces", b"v 0 0 0\nv 1 0 0\n", "a.obj"),
    ("face index out of range", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 5\n", "a.obj"),
    ("face of 2 corners", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "a.obj"),
    ("non-integer index", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", "a.obj"),
    ("non-numeric coordinate", b"v 0 0 zero\nf 1 1 1\n", "a.obj"),
    ("PLY header without end", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n", "a.ply"),
    ("zip named .ply", b"PK\x03\x04 a zip", "a.ply"),
    ("truncated binary PLY", TRUNCATED, "a.ply"),
]


def grid_mesh(n: int = 100) -> Mesh:
    """(n+1)^2 vertices of a bumpy sheet; n^2 cells, every fifth row split into two triangles."""
    ys, xs = np.mgrid[0:n + 1, 0:n + 1].astype(float)
    verts = np.stack([xs, ys, np.sin(xs / 7) * np.cos(ys / 5)], -1).reshape(-1, 3)
    sizes, idx = [], []
    for r in range(n):
        for c in range(n):
            a, b, d, e = r * (n + 1) + c, r * (n + 1) + c + 1, (r + 1) * (n + 1) + c + 1, (r + 1) * (n + 1) + c
            if r % 5 == 0:
                sizes += [3, 3]
                idx += [a, b, d, a, d, e]
            else:
                sizes.append(4)
                idx += [a, b, d, e]
    return Mesh(verts, np.array(sizes, np.int64), np.array(idx, np.int64))


def _trimesh(data: bytes, name: str) -> tuple[np.ndarray, list[list[int]]]:
    import trimesh

    m = trimesh.load(io.BytesIO(data), file_type=Path(name).suffix[1:], process=False, force="mesh")
    return np.asarray(m.vertices), np.asarray(m.faces).tolist()


def _meshio(data: bytes, name: str) -> tuple[np.ndarray, list[list[int]]]:
    import meshio

    with tempfile.TemporaryDirectory() as tmp:  # meshio reads paths
        path = Path(tmp) / name
        path.write_bytes(data)
        m = meshio.read(path)
    return np.asarray(m.points), [list(c) for block in m.cells for c in block.data]


def _plyfile(data: bytes, name: str) -> tuple[np.ndarray, list[list[int]]]:
    from plyfile import PlyData

    if not name.endswith(".ply"):
        raise NotImplementedError("PLY only")
    ply = PlyData.read(io.BytesIO(data))
    v = ply["vertex"]
    faces = ply["face"].data["vertex_indices"] if "face" in ply else []
    return np.stack([v["x"], v["y"], v["z"]], -1), [list(f) for f in faces]


def _ours(data: bytes, name: str) -> tuple[np.ndarray, list[list[int]]]:
    m = read_mesh(data, name)
    starts = np.cumsum(m.face_sizes) - m.face_sizes
    return m.vertices, [m.face_indices[s:s + k].tolist() for s, k in zip(starts, m.face_sizes)]


READERS: dict[str, Callable[[bytes, str], tuple[np.ndarray, list[list[int]]]]] = {
    "ours": _ours, "trimesh": _trimesh, "meshio": _meshio, "plyfile": _plyfile}


HANG_S = 20.0
"""A reader that has not answered a hostile file after this long is counted as hanging."""


def outcome(lib: str, data: bytes, name: str) -> str:
    """How reader ``lib`` answers a file, in a child process (a reader may hang): 'error: <type>',
    'accepted: V vertices, F faces' or 'hangs (> 20 s)'."""
    ctx = multiprocessing.get_context("fork")
    with ctx.Pool(1) as pool:
        job = pool.apply_async(_outcome, (lib, data, name))
        try:
            return job.get(HANG_S)
        except multiprocessing.TimeoutError:
            pool.terminate()
            return f"hangs (> {HANG_S:g} s)"


def _outcome(lib: str, data: bytes, name: str) -> str:
    reader = READERS[lib]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            verts, faces = reader(data, name)
    except NotImplementedError:
        return "n/a"
    except ModuleNotFoundError:
        return "not installed"
    except FaceInputError as exc:
        return f"error: FaceInputError ({str(exc)[:40]})"
    except Exception as exc:  # noqa: BLE001 - what a library raises is what we measure
        return f"error: {type(exc).__name__}"
    return f"accepted: {len(verts)} vertices, {len(faces)} faces"


def main() -> int:
    argparse.ArgumentParser(prog=prog(), description=__doc__.split("\n\n")[0]).parse_args()  # --help: no run
    hostile = {}
    for what, data, name in HOSTILE:
        hostile[what] = {lib: outcome(lib, data, name) for lib in READERS}
        print(what, hostile[what], flush=True)
    refused = {lib: sum(v[lib].startswith("error") for v in hostile.values()) for lib in READERS}
    hangs = {lib: sum(v[lib].startswith("hangs") for v in hostile.values()) for lib in READERS}
    applicable = {lib: sum(v[lib] not in ("n/a", "not installed") for v in hostile.values()) for lib in READERS}

    mesh = grid_mesh()
    files = {"obj": (write_mesh(mesh, "obj"), "a.obj"), "ply binary": (write_mesh(mesh, "ply", True), "a.ply"),
             "ply ascii": (write_mesh(mesh, "ply", False), "a.ply")}
    _, want = _ours(files["obj"][0], "a.obj")
    keeps, speed = {}, {}
    for fmt, (data, name) in files.items():
        anchor = timed(lambda: _ours(data, name), 5, warmup=1).best
        for lib, fn in READERS.items():
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    verts, faces = fn(data, name)
            except (NotImplementedError, ModuleNotFoundError):
                continue
            except Exception as exc:  # noqa: BLE001 - a valid file the library cannot read
                keeps[f"{fmt} {lib}"] = f"fails to read it ({type(exc).__name__}: {str(exc)[:40]})"
                speed[f"{fmt} {lib}"] = {"ms": float("nan"), "over_ours": float("nan")}
                continue
            same = len(verts) == mesh.n_vertices and np.allclose(verts, mesh.vertices, atol=1e-5)
            keeps[f"{fmt} {lib}"] = "yes" if same and faces == want else (
                f"no ({len(faces)} faces{', reordered or split' if len(faces) else ''})")
            best = anchor if lib == "ours" else timed(lambda: fn(data, name), 5, warmup=1).best
            speed[f"{fmt} {lib}"] = {"ms": 1000 * best, "over_ours": best / anchor}
    lavg = load()
    rows = [[what, *(v[lib] for lib in READERS)] for what, v in hostile.items()]
    md = (
        "Hostile files (the cases of tests/faces/test_faces_mesh.py): what each reader does. Refused: "
        + ", ".join(f"{lib} {refused[lib]}/{applicable[lib]}" for lib in READERS) + "; hanging: "
        + ", ".join(f"{lib} {hangs[lib]}" for lib in READERS) + ".\n\n"
        + md_table(["file", *READERS], rows)
        + "\n\nA 10,201-vertex mesh of 8,000 quads and 4,000 triangles in file order: polygons kept exactly (sizes, "
          "order, no triangulation or merging) and read time (fastest of 5, ms; ratio to ours):\n\n"
        + md_table(["file", "reader", "polygons kept", "ms", "x ours"],
                   [[k.rsplit(" ", 1)[0], k.rsplit(" ", 1)[1], keeps[k], v["ms"], v["over_ours"]]
                    for k, v in speed.items()])
        + f"\n\nLoad average during the run: {lavg} (2 cores; other helpers' work was running).\n"
    )
    publish("mesh_io", {"hostile": hostile, "refused": refused, "hangs": hangs, "keeps_polygons": keeps, "speed": speed,
                        "load": lavg}, md)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
