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
from dataclasses import dataclass, field
from typing import Literal

import piexif

from workers.common.images import UnsupportedImage
from workers.orientation.errors import UnwritableExif
from workers.orientation.headers import Ifd0, ImageHeader, parse_header, read_ifd0, riff_chunks

ORIENTATION_TAG = 274
VALID_ORIENTATIONS = range(1, 9)
"""The eight values EXIF defines for Orientation (274)."""
_EXIF_HEADER = b"Exif\x00\x00"
_APP0, _APP1 = 0xE0, 0xE1
_SHORT = 3
_ROTATION_TO_ORIENTATION = {0: 1, 90: 6, 180: 3, 270: 8}

ExifStatus = Literal["absent", "ok", "unreadable"]
TAGGABLE_FORMATS = ("jpeg", "webp")


def orientation_for_rotation(rotation: int) -> int:
    """EXIF Orientation value for a clockwise display rotation of 0, 90, 180 or 270 degrees."""
    try:
        return _ROTATION_TO_ORIENTATION[rotation]
    except KeyError:
        raise ValueError(f"rotation must be 0, 90, 180 or 270 degrees, not {rotation}") from None


def require_orientation(value: int) -> None:
    """ValueError unless ``value`` is one of the eight Orientation values (1-8)."""
    if not 1 <= value <= 8:
        raise ValueError(f"Orientation must be 1-8, not {value}")



@dataclass(frozen=True)
class ExifInfo:
    """The EXIF block of a photo as far as orientation is concerned."""

    status: ExifStatus
    orientation: int | None = None
    """The Orientation value when the block is readable and has the tag."""
    detail: str = ""
    """Why the block is unreadable."""
    ifd0: Ifd0 | None = field(default=None, compare=False, repr=False)
    """A readable block's IFD0 (what the writer edits)."""


def read_exif(data: bytes, header: ImageHeader | None = None) -> ExifInfo:
    """The EXIF state of a JPEG or WebP (``header``: its parsed header, if at hand); UnsupportedImage
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
        ifd0 = read_ifd0(tiff, "block")
    except Exception as exc:  # noqa: BLE001 - piexif raises struct.error, ValueError, KeyError, ...
        return ExifInfo("unreadable", detail=f"{type(exc).__name__}: {exc}")
    value = loaded["0th"].get(ORIENTATION_TAG)
    return ExifInfo("ok", value if isinstance(value, int) else None, ifd0=ifd0)


def tiff_block_state(tiff: bytes) -> ExifInfo:
    """The EXIF state of a bare TIFF structure (an EXIF block without its ``Exif\\0\\0`` header, a PNG
    eXIf chunk, a HEIF EXIF item)."""
    return _tiff_state(tiff)


def write_orientation(data: bytes, value: int, header: ImageHeader | None = None,
                      state: ExifInfo | None = None) -> bytes:
    """``data`` (JPEG or WebP bytes) with EXIF Orientation set to ``value`` (1-8), all else kept.

    ``header`` and ``state`` are the photo's parsed header and its :func:`read_exif` state, when at
    hand (else read here). An unreadable EXIF block is replaced by a valid one holding only the tag
    (check :func:`read_exif` first to report it). Raises UnsupportedImage for other formats and
    UnwritableExif when the edited block would not fit in a JPEG segment (64 KiB).
    """
    require_orientation(value)
    if header is None:
        header = _writable_header(data)
    else:
        require_taggable(header.format)
    tiff = _find_tiff(data, header)
    if state is None:
        state = _tiff_state(tiff)
    if state.status == "ok":
        new_tiff = _set_orientation(tiff, value, state.ifd0)
    else:
        new_tiff = piexif.dump({"0th": {ORIENTATION_TAG: value}})[len(_EXIF_HEADER):]
    if header.format == "webp":
        out = io.BytesIO()
        piexif.insert(_EXIF_HEADER + new_tiff, data, out)
        return out.getvalue()
    return _replace_app1(data, header, new_tiff)


def require_taggable(fmt: str) -> None:
    """Raise UnsupportedImage unless images of format ``fmt`` can carry the tag here (JPEG, WebP)."""
    if fmt not in TAGGABLE_FORMATS:
        raise UnsupportedImage(f"{fmt.upper()} files cannot be given an EXIF Orientation tag here; "
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
    for fourcc, start, end in riff_chunks(data):
        if fourcc == b"EXIF":
            payload = data[start:end]
            return payload[len(_EXIF_HEADER):] if payload.startswith(_EXIF_HEADER) else payload
    return None


def _exif_segment(data: bytes, header: ImageHeader):
    return next((s for s in header.segments
                 if s.marker == _APP1 and data[s.payload][:len(_EXIF_HEADER)] == _EXIF_HEADER), None)


def _set_orientation(tiff: bytes, value: int, ifd0: Ifd0 | None = None) -> bytes:
    """``tiff`` with IFD0's Orientation set to ``value``, every other byte of meaning unchanged (``ifd0``: its
    IFD0, when already read; ValueError when it cannot be)."""
    ifd0 = read_ifd0(tiff, "block") if ifd0 is None else ifd0
    endian, offset, entries, next_ifd = ifd0.endian, ifd0.offset, ifd0.entries, ifd0.next_ifd
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
