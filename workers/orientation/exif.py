"""The EXIF Orientation tag (274): its meaning, reading it, and writing it without touching anything else.

Orientation says how the stored pixels must be turned for display: 1 as stored, 6 turn 90
degrees clockwise, 3 turn 180, 8 turn 90 counter-clockwise (2, 4, 5, 7 add a mirror). A
detected rotation of ``r`` clockwise degrees (see :mod:`workers.orientation.geometry`)
therefore becomes 1, 6, 3, 8 for r = 0, 90, 180, 270.

Writing is lossless. The existing EXIF block is validated with piexif and then edited at the
byte level instead of being re-serialised (piexif drops tags it does not know, and moving data
breaks maker notes that hold absolute offsets):

- the tag exists as one SHORT: its two value bytes are overwritten in place;
- otherwise: IFD0 is copied to the end of the TIFF block with the tag added (entries sorted,
  every other entry byte-identical) and the header's IFD0 offset is pointed at the copy, so no
  other offset in the block changes;
- no EXIF, or EXIF piexif cannot read: a new block holding only the tag (reported to the caller).

Only the Exif APP1 segment of a JPEG (or the EXIF chunk of a WebP) changes; every other segment,
the compressed image data and the thumbnail are byte-identical.
"""
from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from typing import Literal

import piexif

from workers.orientation.errors import UnsupportedFormat, UnwritableExif
from workers.orientation.headers import ImageHeader, parse_header

ORIENTATION_TAG = 274
_EXIF_HEADER = b"Exif\x00\x00"
_APP0, _APP1 = 0xE0, 0xE1
_SHORT = 3
_ROTATION_TO_ORIENTATION = {0: 1, 90: 6, 180: 3, 270: 8}
_ORIENTATION_TO_ROTATION = {v: k for k, v in _ROTATION_TO_ORIENTATION.items()}

ExifStatus = Literal["absent", "ok", "unreadable"]
TAGGABLE_FORMATS = ("jpeg", "webp")


def orientation_for_rotation(rotation: int) -> int:
    """EXIF Orientation value for a clockwise display rotation of 0, 90, 180 or 270 degrees."""
    try:
        return _ROTATION_TO_ORIENTATION[rotation]
    except KeyError:
        raise ValueError(f"rotation must be 0, 90, 180 or 270 degrees, not {rotation}") from None


def rotation_for_orientation(value: int) -> int | None:
    """Clockwise display rotation for Orientation 1, 6, 3, 8; None for mirrored or invalid values."""
    return _ORIENTATION_TO_ROTATION.get(value)


@dataclass(frozen=True)
class ExifInfo:
    """The EXIF block of a photo as far as orientation is concerned."""

    status: ExifStatus
    orientation: int | None = None
    """The Orientation value when the block is readable and has the tag."""
    detail: str = ""
    """Why the block is unreadable."""


def read_exif(data: bytes, header: ImageHeader | None = None) -> ExifInfo:
    """The EXIF state of a JPEG or WebP (``header``: its parsed header, if at hand); UnsupportedFormat
    for other formats."""
    if header is None:
        header = _writable_header(data)
    else:
        require_taggable(header.format)
    return _tiff_state(_find_tiff(data, header))


def _tiff_state(tiff: bytes | None) -> ExifInfo:
    if tiff is None:
        return ExifInfo("absent")
    try:
        loaded = piexif.load(_EXIF_HEADER + tiff)
        _read_ifd0(tiff)
    except Exception as exc:  # noqa: BLE001 - piexif raises struct.error, ValueError, KeyError, ...
        return ExifInfo("unreadable", detail=f"{type(exc).__name__}: {exc}")
    value = loaded["0th"].get(ORIENTATION_TAG)
    return ExifInfo("ok", value if isinstance(value, int) else None)


def tiff_block_state(tiff: bytes) -> ExifInfo:
    """The EXIF state of a bare TIFF structure (an EXIF block without its ``Exif\\0\\0`` header, a PNG
    eXIf chunk, a HEIF EXIF item)."""
    return _tiff_state(tiff)


def write_orientation(data: bytes, value: int) -> bytes:
    """``data`` (JPEG or WebP bytes) with EXIF Orientation set to ``value`` (1-8), all else kept.

    An unreadable EXIF block is replaced by a valid one holding only the tag (check
    :func:`read_exif` first to report it). Raises UnsupportedFormat for other formats and
    UnwritableExif when the edited block would not fit in a JPEG segment (64 KiB).
    """
    if not 1 <= value <= 8:
        raise ValueError(f"EXIF Orientation must be 1-8, not {value}")
    header = _writable_header(data)
    tiff = _find_tiff(data, header)
    if _tiff_state(tiff).status == "ok":
        new_tiff = _set_orientation(tiff, value)
    else:
        new_tiff = piexif.dump({"0th": {ORIENTATION_TAG: value}})[len(_EXIF_HEADER):]
    if header.format == "webp":
        out = io.BytesIO()
        piexif.insert(_EXIF_HEADER + new_tiff, data, out)
        return out.getvalue()
    return _replace_app1(data, header, new_tiff)


def require_taggable(fmt: str) -> None:
    """Raise UnsupportedFormat unless images of format ``fmt`` can carry the tag here (JPEG, WebP)."""
    if fmt not in TAGGABLE_FORMATS:
        raise UnsupportedFormat(f"{fmt.upper()} files cannot be given an EXIF Orientation tag here; "
                                "send a JPEG (or WebP)")


def _writable_header(data: bytes) -> ImageHeader:
    header = parse_header(data)
    require_taggable(header.format)
    return header


def _find_tiff(data: bytes, header: ImageHeader) -> bytes | None:
    """The TIFF structure inside the photo's EXIF block, or None when there is none."""
    if header.format == "jpeg":
        seg = _exif_segment(data, header)
        return None if seg is None else data[seg.payload][len(_EXIF_HEADER):]
    for fourcc, payload in _riff_chunks(data):
        if fourcc == b"EXIF":
            return payload[len(_EXIF_HEADER):] if payload.startswith(_EXIF_HEADER) else payload
    return None


def _exif_segment(data: bytes, header: ImageHeader):
    return next((s for s in header.segments
                 if s.marker == _APP1 and data[s.payload][:len(_EXIF_HEADER)] == _EXIF_HEADER), None)


def _riff_chunks(data: bytes):
    pos = 12
    while pos + 8 <= len(data):
        fourcc, size = data[pos:pos + 4], struct.unpack_from("<I", data, pos + 4)[0]
        yield fourcc, data[pos + 8:pos + 8 + size]
        pos += 8 + size + (size & 1)


def _read_ifd0(tiff: bytes) -> tuple[str, int, list[bytes], bytes]:
    """(endian, IFD0 offset, raw 12-byte entries, raw 4-byte next-IFD pointer); ValueError if malformed."""
    if tiff[:4] not in (b"II*\x00", b"MM\x00*"):
        raise ValueError("not a TIFF header")
    endian = "<" if tiff[:2] == b"II" else ">"
    offset = struct.unpack_from(endian + "I", tiff, 4)[0]
    if offset < 8 or offset + 2 > len(tiff):
        raise ValueError(f"IFD0 offset {offset} outside the block")
    count = struct.unpack_from(endian + "H", tiff, offset)[0]
    end = offset + 2 + 12 * count
    if end + 4 > len(tiff):
        raise ValueError(f"IFD0 with {count} entries runs past the block")
    entries = [tiff[offset + 2 + 12 * i:offset + 14 + 12 * i] for i in range(count)]
    return endian, offset, entries, tiff[end:end + 4]


def _set_orientation(tiff: bytes, value: int) -> bytes:
    """``tiff`` with IFD0's Orientation set to ``value``, every other byte of meaning unchanged."""
    endian, offset, entries, next_ifd = _read_ifd0(tiff)
    tags = [struct.unpack_from(endian + "H", e)[0] for e in entries]
    if ORIENTATION_TAG in tags:
        i = tags.index(ORIENTATION_TAG)
        vtype, count = struct.unpack_from(endian + "HI", entries[i], 2)
        if vtype == _SHORT and count == 1:
            pos = offset + 2 + 12 * i + 8
            return tiff[:pos] + struct.pack(endian + "H", value) + tiff[pos + 2:]
    new_entry = struct.pack(endian + "HHI", ORIENTATION_TAG, _SHORT, 1) + struct.pack(endian + "H", value) + b"\0\0"
    kept = [(t, e) for t, e in zip(tags, entries) if t != ORIENTATION_TAG] + [(ORIENTATION_TAG, new_entry)]
    kept.sort(key=lambda te: te[0])
    pad = b"\0" * (len(tiff) & 1)  # IFDs start on a word boundary
    new_offset = len(tiff) + len(pad)
    ifd = struct.pack(endian + "H", len(kept)) + b"".join(e for _, e in kept) + next_ifd
    return tiff[:4] + struct.pack(endian + "I", new_offset) + tiff[8:] + pad + ifd


def _replace_app1(data: bytes, header: ImageHeader, tiff: bytes) -> bytes:
    """The JPEG with its Exif APP1 payload replaced (or a new APP1 after SOI and any JFIF APP0)."""
    payload = _EXIF_HEADER + tiff
    if len(payload) + 2 > 0xFFFF:
        raise UnwritableExif(f"the EXIF block would grow to {len(payload)} bytes, more than a JPEG segment holds")
    segment = b"\xff" + bytes([_APP1]) + struct.pack(">H", len(payload) + 2) + payload
    old = _exif_segment(data, header)
    if old is not None:
        return data[:old.start] + segment + data[old.end:]
    first = header.segments[0] if header.segments else None
    pos = first.end if first is not None and first.marker == _APP0 else 2
    return data[:pos] + segment + data[pos:]
