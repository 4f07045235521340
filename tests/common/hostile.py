"""Builders of hostile inputs shared by the tests: image bombs and zip archives that lie."""
from __future__ import annotations

import io
import struct
import zipfile
import zlib

import numpy as np

from tests.orientation.builders import jpeg


def png_bomb(width: int, height: int) -> bytes:
    """A grey 8-bit PNG of ``width`` x ``height`` zeros: tens of kilobytes that decode to width x height bytes."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    rows = zlib.compress(b"\0" * ((width + 1) * height), 9)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", rows) + chunk(b"IEND", b""))


def jpeg_declaring(width: int, height: int) -> bytes:
    """A JPEG whose frame header (SOF0) declares ``width`` x ``height``; the rest is a valid small image."""
    small = jpeg(np.zeros((8, 8, 3), np.uint8))
    sof = small.index(b"\xff\xc0")
    return small[:sof + 5] + struct.pack(">HH", height, width) + small[sof + 9:]


def zip_with(*members: tuple[str, bytes]) -> bytes:
    """A deflated zip of (name, bytes) members."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in members:
            zf.writestr(name, data)
    return buf.getvalue()


def zip_understating(name: str, size: int, declared: int) -> bytes:
    """A zip whose one member holds ``size`` zero bytes but whose headers declare ``declared``."""
    data = bytearray(zip_with((name, b"\0" * size)))
    struct.pack_into("<I", data, 22, declared)  # local file header: uncompressed size
    central = data.index(b"PK\x01\x02")
    struct.pack_into("<I", data, central + 24, declared)  # central directory: uncompressed size
    return bytes(data)
