"""HEIF / AVIF (ISO base media file format) boxes read without decoding: brands, the primary item's
size and its display transform (``irot``, ``imir``).

In HEIF and AVIF the stored ("coded") image is turned for display by the transformative properties
of the primary item, in the order they are listed: ``irot`` turns it counter-clockwise by 90 degrees
times its ``angle`` (0-3) and ``imir`` mirrors it (axis 0: top and bottom swap, i.e. a vertical
flip; axis 1: left and right swap, a horizontal flip). Readers that follow the HEIF standard
(libheif, browsers) apply these and ignore any EXIF/XMP Orientation the file also carries, so that
tag is only information here. This module reads the boxes; it never writes a HEIF file.

Only what orientation needs is parsed: ``ftyp``; ``meta`` > ``pitm`` (primary item),
``iprp`` > ``ipco`` (the properties) and ``ipma`` (which properties belong to which item).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

HEIF_BRANDS = frozenset({b"heic", b"heix", b"heim", b"heis", b"hevc", b"hevx", b"hevm", b"hevs", b"mif1",
                         b"msf1", b"mif2"})
AVIF_BRANDS = frozenset({b"avif", b"avis"})


class BoxError(ValueError):
    """The box structure is damaged or truncated (``truncated`` says which)."""

    def __init__(self, message: str, truncated: bool = False) -> None:
        super().__init__(message)
        self.truncated = truncated


@dataclass(frozen=True)
class HeifInfo:
    """What a HEIF/AVIF file's boxes say about its primary image."""

    kind: str
    """"heif" or "avif" (from the brands)."""
    width: int | None
    """Coded width (px) of the primary image (``ispe``), before irot/imir; None when absent."""
    height: int | None
    irot: int | None
    """Counter-clockwise quarter turns (0-3) of the ``irot`` property; None when absent."""
    imir: int | None
    """Mirror axis of the ``imir`` property (0: vertical flip, 1: horizontal flip); None when absent."""
    transforms: tuple[tuple[str, int], ...] = ()
    """The primary item's transformative properties in file order: ("irot", angle) / ("imir", axis)."""


def brand_kind(data: bytes) -> str | None:
    """"avif", "heif" or None from the ``ftyp`` box at the start of ``data``."""
    if len(data) < 12 or data[4:8] != b"ftyp":
        return None
    size = struct.unpack_from(">I", data, 0)[0]
    body = data[8:min(max(size, 16), len(data), 4096)]
    brands = {body[0:4]} | {body[i:i + 4] for i in range(8, len(body) - 3, 4)}
    if brands & AVIF_BRANDS and (body[0:4] in AVIF_BRANDS or not brands & (HEIF_BRANDS - {b"mif1", b"msf1"})):
        return "avif"
    if brands & HEIF_BRANDS:
        return "heif"
    return None


def _boxes(data: bytes, start: int, end: int):
    """(type, body start, body end) of each box in ``data[start:end]``; BoxError when one runs past ``end``."""
    pos = start
    while pos + 8 <= end:
        size, kind = struct.unpack_from(">I4s", data, pos)
        header = 8
        if size == 1:
            if pos + 16 > end:
                raise BoxError(f"box {kind!r} at byte {pos} ends inside its size", truncated=True)
            size = struct.unpack_from(">Q", data, pos + 8)[0]
            header = 16
        elif size == 0:
            size = end - pos
        if size < header:
            raise BoxError(f"box {kind!r} at byte {pos} has size {size}")
        if pos + size > end:
            raise BoxError(f"box {kind!r} at byte {pos} needs {size} bytes, only {end - pos} remain", truncated=True)
        yield kind, pos + header, pos + size
        pos += size


def read_heif(data: bytes) -> HeifInfo:
    """The primary image's size and transform of a HEIF/AVIF file; BoxError when the boxes are damaged."""
    kind = brand_kind(data)
    if kind is None:
        raise BoxError("no HEIF/AVIF ftyp box")
    meta = next(((s, e) for k, s, e in _boxes(data, 0, len(data)) if k == b"meta"), None)
    if meta is None:
        raise BoxError("no meta box (the file is truncated or not a HEIF image)", truncated=True)
    m_start, m_end = meta[0] + 4, meta[1]  # meta is a full box: version and flags first
    primary = None
    ipco: list[tuple[bytes, int, int]] = []
    assoc: dict[int, list[int]] = {}
    for kind_, s, e in _boxes(data, m_start, m_end):
        if kind_ == b"pitm":
            version = data[s]
            primary = struct.unpack_from(">H" if version == 0 else ">I", data, s + 4)[0]
        elif kind_ == b"iprp":
            for k2, s2, e2 in _boxes(data, s, e):
                if k2 == b"ipco":
                    ipco = list(_boxes(data, s2, e2))
                elif k2 == b"ipma":
                    assoc.update(_ipma(data, s2, e2))
    if primary is None:
        raise BoxError("no primary item (pitm box)")
    width = height = irot = imir = None
    transforms: list[tuple[str, int]] = []
    for index in assoc.get(primary, []):
        if not 1 <= index <= len(ipco):
            continue
        k, s, e = ipco[index - 1]
        if k == b"ispe" and e - s >= 12:
            width, height = struct.unpack_from(">II", data, s + 4)
        elif k == b"irot" and e > s:
            irot = data[s] & 0x03
            transforms.append(("irot", irot))
        elif k == b"imir" and e > s:
            imir = data[s] & 0x01
            transforms.append(("imir", imir))
    return HeifInfo(kind, width, height, irot, imir, tuple(transforms))


def _ipma(data: bytes, start: int, end: int) -> dict[int, list[int]]:
    version, flags = data[start], int.from_bytes(data[start + 1:start + 4], "big")
    pos = start + 4
    count = struct.unpack_from(">I", data, pos)[0]
    pos += 4
    out: dict[int, list[int]] = {}
    for _ in range(count):
        if pos + (2 if version < 1 else 4) + 1 > end:
            raise BoxError("ipma box runs past its end")
        item = struct.unpack_from(">H" if version < 1 else ">I", data, pos)[0]
        pos += 2 if version < 1 else 4
        n = data[pos]
        pos += 1
        indices = []
        for _ in range(n):
            if flags & 1:
                indices.append(struct.unpack_from(">H", data, pos)[0] & 0x7FFF)
                pos += 2
            else:
                indices.append(data[pos] & 0x7F)
                pos += 1
        out[item] = indices
    return out
