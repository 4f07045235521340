"""Reading back the PLY files the engines write (binary little-endian, one vertex element)."""
from __future__ import annotations

import numpy as np

_TYPES = {"float": "<f4", "uchar": "u1", "int": "<i4", "double": "<f8"}


def read_ply(data: bytes) -> np.ndarray:
    """A binary little-endian PLY's vertices as a numpy structured array, one field per property."""
    end = data.index(b"end_header\n") + len(b"end_header\n")
    lines = data[:end].decode("ascii").split("\n")
    if "format binary_little_endian 1.0" not in lines:
        raise ValueError("not a binary little-endian PLY")
    dtype = [(ln.split()[2], _TYPES[ln.split()[1]]) for ln in lines if ln.startswith("property ")]
    n = next(int(ln.split()[2]) for ln in lines if ln.startswith("element vertex"))
    return np.frombuffer(data, dtype=dtype, count=n, offset=end)
