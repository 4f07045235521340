"""Image containers read without decoding: format, pixel size and whether the file is whole.

Formats: JPEG, PNG, WebP, TIFF (classic, either byte order), HEIF/HEIC and AVIF (ISO base media
boxes, :mod:`workers.orientation.bmff`) and camera RAW (recognised by magic or, for the TIFF-based
ones, by the file name's extension; their pixels are read from the embedded preview).

The pixel size comes from the header (JPEG SOFn, PNG IHDR, WebP VP8/VP8L/VP8X, TIFF IFD0
ImageWidth/ImageLength, HEIF ``ispe``), so a
decompression bomb is refused before a single pixel is decoded. Completeness is checked on the
container structure: a JPEG's marker segments and entropy-coded scans up to EOI (bytes after
EOI, such as a motion-photo trailer, are allowed), a PNG's chunks up to IEND, a WebP's RIFF size.
"""
from __future__ import annotations

import re
import struct
from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal

from workers.orientation.bmff import BoxError, brand_kind, read_heif
from workers.common.images import EmptyImage, NotAnImage, TooManyPixels, UnreadableImage, UnsupportedImage
from workers.orientation.errors import TruncatedImage

ImageFormat = Literal["jpeg", "png", "webp", "tiff", "heif", "avif", "raw"]
Damage = Literal["truncated", "corrupt"]

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# Recognised image formats that this engine does not decode: (magic at offset, name).
_OTHER_FORMATS: tuple[tuple[int, bytes, str], ...] = (
    (0, b"GIF87a", "GIF"), (0, b"GIF89a", "GIF"), (0, b"BM", "BMP"),
    (0, b"II+\x00", "BigTIFF"), (0, b"MM\x00+", "BigTIFF"), (0, b"8BPS", "Photoshop PSD"),
    (0, b"\x00\x00\x00\x0cjP  ", "JPEG 2000"), (0, b"\xff\x0a", "JPEG XL"),
    (0, b"\x00\x00\x00\x0cJXL ", "JPEG XL"), (0, b"qoif", "QOI"), (0, b"\x00\x00\x01\x00", "ICO"),
)
# SOFn markers carry the frame size; C4 (DHT), C8 (JPG) and CC (DAC) share the range but do not.
_SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
_STANDALONE_MARKERS = frozenset(range(0xD0, 0xD8)) | {0x01}
_SOS, _EOI = 0xDA, 0xD9
# Inside entropy-coded data 0xFF is followed by 0x00 (stuffing) or a restart marker D0-D7;
# anything else ends the scan.
_END_OF_SCAN = re.compile(rb"\xff[^\x00\xd0-\xd7]")


@dataclass(frozen=True)
class Segment:
    """One JPEG marker segment: ``data[start:end]`` is ``FF marker length payload``."""

    marker: int
    start: int
    end: int

    @property
    def payload(self) -> slice:
        return slice(self.start + 4, self.end)


@dataclass(frozen=True)
class Ifd0:
    """The first image directory (IFD0) of a classic TIFF structure: a TIFF file, or the TIFF inside an EXIF block."""

    endian: str
    """``<`` (II) or ``>`` (MM)."""
    offset: int
    entries: tuple[bytes, ...]
    """The raw 12-byte entries, in file order."""
    next_ifd: bytes
    """The raw 4-byte pointer to the next IFD."""

    @cached_property
    def tags(self) -> dict[int, tuple[int, int, bytes]]:
        """{tag: (field type, count, the entry's 4 value bytes)}; a tag listed twice: its last entry."""
        out = {}
        for entry in self.entries:
            tag, ftype, count = struct.unpack_from(self.endian + "HHI", entry)
            out[tag] = (ftype, count, entry[8:12])
        return out


@dataclass(frozen=True)
class ImageHeader:
    """What the container says about an image, read without decoding it."""

    format: ImageFormat
    width: int | None
    height: int | None
    damage: Damage | None = None
    detail: str = ""
    segments: tuple[Segment, ...] = field(default=())
    """JPEG only: the marker segments before the first scan (APPn, DQT, SOFn, DHT, ..., SOS)."""
    ifd0: Ifd0 | None = field(default=None, repr=False)
    """TIFF only: its first image directory, when it could be read."""

    @property
    def pixels(self) -> int | None:
        return None if self.width is None or self.height is None else self.width * self.height


SUPPORTED_TEXT = "JPEG, PNG, WebP, TIFF, HEIC/HEIF, AVIF or a camera RAW file"
RAW_EXTENSIONS = frozenset({
    ".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".orf", ".rw2", ".raf", ".pef",
    ".srw", ".rwl", ".3fr", ".fff", ".iiq", ".erf", ".mef", ".mos", ".mrw", ".kdc", ".dcr", ".x3f"})
"""File name extensions of camera RAW formats: never written, given an XMP sidecar instead."""
# RAW formats with their own magic (the TIFF-based ones are told apart by extension).
_RAW_MAGIC: tuple[tuple[int, bytes], ...] = (
    (8, b"CR\x02\x00"), (4, b"ftypcrx "), (0, b"IIRO"), (0, b"IIRS"), (0, b"MMOR"), (0, b"IIU\x00"),
    (0, b"FUJIFILMCCD-RAW"), (0, b"FOVb"), (0, b"\x00MRM"))


def sniff_format(data: bytes, filename: str | None = None) -> ImageFormat:
    """The container format from the magic bytes (and, for TIFF-based RAW, the extension of
    ``filename``); raises EmptyImage, UnsupportedImage, NotAnImage."""
    if len(data) == 0:
        raise EmptyImage("the file is empty (0 bytes)")
    if data[:3] == b"\xff\xd8\xff":
        return "jpeg"
    if data[:8] == _PNG_SIGNATURE:
        return "png"
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return "webp"
    if any(data[o:o + len(m)] == m for o, m in _RAW_MAGIC):
        return "raw"
    if data[:4] in (b"II*\x00", b"MM\x00*"):
        ext = ("." + filename.rsplit(".", 1)[-1].lower()) if filename and "." in filename else ""
        return "raw" if ext in RAW_EXTENSIONS else "tiff"
    kind = brand_kind(data)
    if kind is not None:
        return kind  # type: ignore[return-value]
    for offset, magic, name in _OTHER_FORMATS:
        if data[offset:offset + len(magic)] == magic:
            raise UnsupportedImage(f"{name} images are not supported; send {SUPPORTED_TEXT}")
    raise NotAnImage(f"not an image: the first bytes ({data[:8].hex(' ')}) match no {SUPPORTED_TEXT} header")


def parse_header(data: bytes, filename: str | None = None) -> ImageHeader:
    """Format, pixel size and completeness of ``data`` (never decodes pixels). A RAW file's size is
    unknown here (None: its embedded preview's is checked when it is read)."""
    fmt = sniff_format(data, filename)
    if fmt == "jpeg":
        return _parse_jpeg(data)
    if fmt == "png":
        return _parse_png(data)
    if fmt == "webp":
        return _parse_webp(data)
    if fmt == "tiff":
        return _parse_tiff(data)
    if fmt in ("heif", "avif"):
        return _parse_heif(data, fmt)
    return ImageHeader("raw", None, None)


def check_header(header: ImageHeader, max_pixels: int) -> None:
    """Raise the error a person should see for this header: size first (a bomb), then damage."""
    if header.pixels is None and header.format == "raw" and header.damage is None:
        return  # the embedded preview is checked when it is read
    if header.pixels is None:
        cls = TruncatedImage if header.damage == "truncated" else UnreadableImage
        raise cls(f"the {header.format.upper()} file ends or breaks before its image size: {header.detail}")
    if header.width <= 0 or header.height <= 0:
        raise UnreadableImage(f"the {header.format.upper()} header gives an empty size {header.width}x{header.height}")
    if header.pixels > max_pixels:
        raise TooManyPixels(
            f"the image is {header.width}x{header.height} = {header.pixels:,} pixels; "
            f"the limit is {max_pixels:,} pixels")
    if header.damage == "truncated":
        raise TruncatedImage(f"the {header.format.upper()} file is incomplete (truncated): {header.detail}")
    if header.damage == "corrupt":
        raise UnreadableImage(f"the {header.format.upper()} file is damaged: {header.detail}")


def _parse_jpeg(data: bytes) -> ImageHeader:
    n = len(data)
    pos = 2
    width = height = None
    segments: list[Segment] = []
    in_header = True

    def result(damage: Damage | None, detail: str = "") -> ImageHeader:
        return ImageHeader("jpeg", width, height, damage, detail, tuple(segments))

    while True:
        if pos >= n:
            return result("truncated", f"no end-of-image marker (file ends at byte {n})")
        if data[pos] != 0xFF:
            return result("corrupt", f"expected a marker at byte {pos}, found 0x{data[pos]:02x}")
        while pos + 1 < n and data[pos + 1] == 0xFF:  # fill bytes
            pos += 1
        if pos + 1 >= n:
            return result("truncated", f"file ends inside a marker at byte {pos}")
        marker = data[pos + 1]
        if marker == _EOI:
            return result(None)
        if marker in _STANDALONE_MARKERS:
            pos += 2
            continue
        if pos + 4 > n:
            return result("truncated", f"file ends inside the length of marker 0x{marker:02x}")
        length = struct.unpack_from(">H", data, pos + 2)[0]
        end = pos + 2 + length
        if length < 2:
            return result("corrupt", f"marker 0x{marker:02x} at byte {pos} has length {length}")
        if end > n:
            return result("truncated", f"segment 0x{marker:02x} at byte {pos} needs {length} bytes, file ends at {n}")
        if in_header:
            segments.append(Segment(marker, pos, end))
        if marker in _SOF_MARKERS and width is None:
            if length < 8:
                return result("corrupt", f"frame header at byte {pos} is too short")
            height, width = struct.unpack_from(">HH", data, pos + 5)
        pos = end
        if marker == _SOS:
            in_header = False
            match = _END_OF_SCAN.search(data, pos)
            if match is None:
                return result("truncated", f"the compressed data stops at byte {n} without an end-of-image marker")
            pos = match.start()


def _parse_png(data: bytes) -> ImageHeader:
    n = len(data)
    if n < 33 or data[12:16] != b"IHDR":
        damage: Damage = "truncated" if n < 33 else "corrupt"
        return ImageHeader("png", None, None, damage, "missing IHDR header chunk")
    width, height = struct.unpack_from(">II", data, 16)
    pos = 8
    while pos + 8 <= n:
        length, ctype = struct.unpack_from(">I4s", data, pos)
        end = pos + 12 + length
        if end > n:
            return ImageHeader("png", width, height, "truncated", f"chunk {ctype!r} at byte {pos} runs past the end")
        if ctype == b"IEND":
            return ImageHeader("png", width, height)
        pos = end
    return ImageHeader("png", width, height, "truncated", "no IEND chunk")


def riff_chunks(data: bytes):
    """(fourcc, start of data, end of data) of each chunk of a RIFF file (a WebP) after its 12-byte header."""
    pos = 12
    while pos + 8 <= len(data):
        fourcc, size = data[pos:pos + 4], struct.unpack_from("<I", data, pos + 4)[0]
        yield fourcc, pos + 8, pos + 8 + size
        pos += 8 + size + (size & 1)


def _parse_webp(data: bytes) -> ImageHeader:
    n = len(data)
    if n < 30:
        return ImageHeader("webp", None, None, "truncated", f"only {n} bytes")
    riff_size = struct.unpack_from("<I", data, 4)[0]
    fourcc = data[12:16]
    width = height = None
    if fourcc == b"VP8X":
        width = 1 + int.from_bytes(data[24:27], "little")
        height = 1 + int.from_bytes(data[27:30], "little")
    elif fourcc == b"VP8L":
        if data[20] != 0x2F:
            return ImageHeader("webp", None, None, "corrupt", "bad VP8L signature")
        bits = int.from_bytes(data[21:25], "little")
        width, height = 1 + (bits & 0x3FFF), 1 + ((bits >> 14) & 0x3FFF)
    elif fourcc == b"VP8 ":
        if data[23:26] != b"\x9d\x01\x2a":
            return ImageHeader("webp", None, None, "corrupt", "bad VP8 start code")
        w, h = struct.unpack_from("<HH", data, 26)
        width, height = w & 0x3FFF, h & 0x3FFF
    else:
        return ImageHeader("webp", None, None, "corrupt", f"unknown first chunk {fourcc!r}")
    if riff_size + 8 > n:
        return ImageHeader("webp", width, height, "truncated", f"RIFF says {riff_size + 8} bytes, file has {n}")
    return ImageHeader("webp", width, height)


_TIFF_TYPES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8, 13: 4}
"""TIFF field type -> bytes per value."""


_IFD0_ERRORS = {
    "file": ("not a classic TIFF header", "IFD0 offset {offset} lies outside the {size}-byte file",
             "IFD0 with {count} entries runs past the end of the file"),
    "block": ("not a TIFF header", "IFD0 offset {offset} outside the block",
              "IFD0 with {count} entries runs past the block"),
}
"""What :func:`read_ifd0` says about a damaged IFD0 of a TIFF file and of an EXIF block (reports quote it)."""


def read_ifd0(data: bytes, within: Literal["file", "block"] = "file") -> Ifd0:
    """IFD0 of the classic TIFF structure ``data``: a TIFF file, or (``block``) the TIFF inside an EXIF block;
    ValueError when it is not a TIFF structure or IFD0 lies outside the data."""
    not_tiff, outside, past = _IFD0_ERRORS[within]
    if data[:4] not in (b"II*\x00", b"MM\x00*"):
        raise ValueError(not_tiff)
    endian = "<" if data[:2] == b"II" else ">"
    offset = struct.unpack_from(endian + "I", data, 4)[0]
    if offset < 8 or offset + 2 > len(data):
        raise ValueError(outside.format(offset=offset, size=len(data)))
    count = struct.unpack_from(endian + "H", data, offset)[0]
    end = offset + 2 + 12 * count
    if end + 4 > len(data):
        raise ValueError(past.format(count=count))
    entries = tuple(data[offset + 2 + 12 * i:offset + 14 + 12 * i] for i in range(count))
    return Ifd0(endian, offset, entries, data[end:end + 4])


def tiff_values(data: bytes, endian: str, entry: tuple[int, int, bytes]) -> list[int] | None:
    """The unsigned integer values (BYTE, SHORT, LONG) of an IFD entry, inline or at its offset; None for
    other types or values outside the data."""
    ftype, count, raw = entry
    code = {1: "B", 3: "H", 4: "I", 7: "B", 16: "Q"}.get(ftype)
    if code is None:
        return None
    size = _TIFF_TYPES.get(ftype, 8) * count
    if size <= 4:
        return list(struct.unpack_from(endian + code * count, raw))
    offset = struct.unpack_from(endian + "I", raw)[0]
    if offset + size > len(data) or count > 1_000_000:
        return None
    return list(struct.unpack_from(endian + code * count, data, offset))


def _parse_tiff(data: bytes) -> ImageHeader:
    n = len(data)
    if n < 16:
        return ImageHeader("tiff", None, None, "truncated", f"only {n} bytes")
    try:
        ifd0 = read_ifd0(data)
    except ValueError as exc:
        return ImageHeader("tiff", None, None, "truncated", str(exc))
    endian, tags = ifd0.endian, ifd0.tags
    width = tiff_values(data, endian, tags[256]) if 256 in tags else None
    height = tiff_values(data, endian, tags[257]) if 257 in tags else None
    if not width or not height:
        return ImageHeader("tiff", None, None, "corrupt", "IFD0 has no ImageWidth/ImageLength", ifd0=ifd0)
    w, h = width[0], height[0]
    for offsets_tag, counts_tag in ((273, 279), (324, 325)):  # strips, tiles
        if offsets_tag in tags and counts_tag in tags:
            offsets = tiff_values(data, endian, tags[offsets_tag])
            counts = tiff_values(data, endian, tags[counts_tag])
            if offsets is None or counts is None:
                return ImageHeader("tiff", w, h, "truncated", "the strip/tile tables lie outside the file", ifd0=ifd0)
            end = max((a + b for a, b in zip(offsets, counts)), default=0)
            if end > n:
                return ImageHeader("tiff", w, h, "truncated", f"the image data runs to byte {end}, the file has {n}",
                                   ifd0=ifd0)
    return ImageHeader("tiff", w, h, ifd0=ifd0)


def _parse_heif(data: bytes, fmt: ImageFormat) -> ImageHeader:
    try:
        info = read_heif(data)
    except BoxError as exc:
        return ImageHeader(fmt, None, None, "truncated" if exc.truncated else "corrupt", str(exc))
    except (struct.error, IndexError) as exc:
        return ImageHeader(fmt, None, None, "corrupt", f"damaged boxes ({exc})")
    if info.width is None:
        return ImageHeader(fmt, None, None, "corrupt", "the primary image has no size (ispe) property")
    return ImageHeader(fmt, info.width, info.height)
