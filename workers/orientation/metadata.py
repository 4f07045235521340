"""Where a photo keeps its orientation, in every format a photo library holds, and writing it there.

Reading (:func:`inspect`) lists every place that states an orientation, as *sources*:

- ``exif-ifd0``: the EXIF Orientation tag: a JPEG's Exif APP1, a WebP's EXIF chunk, a TIFF's own IFD0,
  a PNG's ``eXIf`` chunk (or ImageMagick's "Raw profile type exif" text chunk), a RAW file's IFD0;
- ``xmp-embedded``: ``tiff:Orientation`` in the packet inside the file;
- ``xmp-sidecar``: ``tiff:Orientation`` in ``photo.ext.xmp`` / ``photo.xmp`` beside it;
- ``heif-transform``: the ``irot``/``imir`` properties of a HEIF/AVIF primary image (what HEIF
  readers apply), as the equal EXIF value;
- ``heif-exif``: the EXIF item of a HEIF file (information only: HEIF readers ignore it).

Sources that state different valid values are a *conflict* (reported; a write makes the places it
touches agree). What viewers show now (:meth:`Inspection.shown`) is the heif-transform for HEIF/AVIF,
else the EXIF tag, else the embedded XMP.

Writing (:func:`write_in_file`, :func:`sidecar_for`) goes where the format keeps the tag, with the
tool that keeps most of the original:

| format | target | writer |
|---|---|---|
| JPEG, WebP | ``exif-ifd0`` | our byte-level writer (:mod:`workers.orientation.exif`) |
| TIFF (classic, LE/BE, any page count) | ``exif-ifd0`` | our byte-level writer (the same IFD0 edit) |
| PNG | ``png-exif`` (``eXIf`` before IDAT) | ExifTool |
| HEIF, AVIF, RAW, BigTIFF | ``xmp-sidecar`` (never inside the file) | new: our template; existing: in place or ExifTool |

An embedded XMP packet holding ``tiff:Orientation`` is patched to agree (same length, in place:
:func:`workers.orientation.xmp.patch_packet`; PNG's through ExifTool). ``benchmarks/orientation_writers.py``
(section orientation_writers) measures each of our writers against Exiv2 (pyexiv2) and ExifTool.
"""
from __future__ import annotations

import io
import re
import struct
import tempfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, Field

from workers.orientation import exiftool
from workers.orientation.bmff import BoxError, HeifInfo, read_heif
from workers.common.images import UnreadableImage, UnsupportedImage
from workers.orientation.exif import (ORIENTATION_TAG, VALID_ORIENTATIONS, ExifInfo, _set_orientation, read_exif,
                                      require_orientation, tiff_block_state, write_orientation)
from workers.orientation.geometry import heif_orientation
from workers.orientation.headers import Ifd0, ImageFormat, ImageHeader, read_ifd0, riff_chunks, tiff_values
from workers.orientation.xmp import XmpOrientation, patch_packet, read_packet, sidecar_bytes

SourceKind = Literal["exif-ifd0", "xmp-embedded", "xmp-sidecar", "heif-transform", "heif-exif"]
Target = Literal["exif-ifd0", "png-exif", "xmp-sidecar", "none"]
WriteMode = Literal["file", "sidecar"]
"""``file``: into the photo where its format allows (else a sidecar); ``sidecar``: always a sidecar."""

IN_FILE_TARGET: dict[str, Target] = {"jpeg": "exif-ifd0", "webp": "exif-ifd0", "tiff": "exif-ifd0",
                                     "png": "png-exif"}
"""Formats whose files take the tag, and where; every other format gets an XMP sidecar."""
XMP_JPEG_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
_XMP_TIFF_TAG = 700
_PNG_XMP_KEY = b"XML:com.adobe.xmp"
_PNG_RAW_EXIF_KEY = b"Raw profile type exif"
_TEMPLATE = (
    "<?xpacket begin=\"\ufeff\" id=\"W5M0MpCehiHzreSzNTczkc9d\"?>\n"
    "<x:xmpmeta xmlns:x=\"adobe:ns:meta/\" x:xmptk=\"sweepcast\">\n"
    " <rdf:RDF xmlns:rdf=\"http://www.w3.org/1999/02/22-rdf-syntax-ns#\">\n"
    "  <rdf:Description rdf:about=\"\"\n"
    "    xmlns:tiff=\"http://ns.adobe.com/tiff/1.0/\"\n"
    "   tiff:Orientation=\"{value}\"/>\n"
    " </rdf:RDF>\n"
    "</x:xmpmeta>\n"
    "<?xpacket end=\"w\"?>\n")


class OrientationSource(BaseModel):
    """One place in or beside a photo that states an orientation."""

    kind: SourceKind
    where: str = Field(description="the place: 'Exif APP1 IFD0', 'eXIf chunk', 'photo.jpg.xmp', 'irot/imir', ...")
    value: int | None = Field(description="the value as stored (EXIF meaning, 1-8); may be invalid (0, 9, ...)")
    valid: bool = Field(description="value is one of the eight EXIF orientations")
    applied_by_viewers: bool = Field(description="false for places this format's viewers ignore (a HEIF's EXIF item, "
                                                 "ImageMagick's PNG text chunk)")
    detail: str | None = Field(None, description="why the place could not be read, when it could not")


class WritePlan(BaseModel):
    """What writing the detected orientation does, and where."""

    target: Target = Field(description="exif-ifd0 (the file's EXIF Orientation), png-exif (a PNG's eXIf chunk, "
                                       "before IDAT), xmp-sidecar (tiff:Orientation in an XMP file beside the "
                                       "photo; the photo untouched), none (nothing to write)")
    where: str | None = Field(description="the file written: the photo itself, or the sidecar's name")
    value: int | None = Field(description="the Orientation written (1-8); null when nothing is written")
    also: list[str] = Field(default_factory=list, description="other places updated to agree with it (the embedded "
                                                              "XMP packet, existing sidecars)")
    writer: str | None = Field(description="what writes it: 'sweepcast' (byte-level edit) or 'exiftool'")
    note: str | None = Field(None, description="why this target (e.g. HEIF files are never written)")


@dataclass
class Inspection:
    """Every orientation a photo states (its sources), and what the writers need to know."""

    format: ImageFormat
    sources: list[OrientationSource]
    exif: ExifInfo | None
    """The EXIF block's state for JPEG/WebP/TIFF/PNG/RAW (None for HEIF/AVIF)."""
    heif: HeifInfo | None = None
    xmp_value: int | None = None
    """The embedded packet's tiff:Orientation, when it has one."""
    sidecars: dict[str, XmpOrientation] = field(default_factory=dict)
    """Sidecar name -> what it says."""
    bigtiff: bool = False
    header: ImageHeader | None = None
    """The photo's parsed header (what the writers edit)."""
    xmp_span: tuple[int, int] | None = None
    """Where the embedded packet lies in the photo's bytes (JPEG, WebP, TIFF), when it has one."""

    def shown(self) -> int | None:
        """The orientation viewers apply now: HEIF/AVIF irot/imir; else the valid EXIF tag; else the
        embedded XMP's; 1 when the file states none; None when its only statement is invalid or unreadable."""
        if self.format in ("heif", "avif"):
            return self.value_of("heif-transform") or 1
        tag = self.value_of("exif-ifd0", applied_only=True)
        if tag is not None:
            return tag
        if self.exif is not None and self.exif.status == "unreadable":
            return None
        if any(s.kind == "exif-ifd0" and s.applied_by_viewers and not s.valid for s in self.sources):
            return None
        return self.value_of("xmp-embedded", applied_only=True) or 1

    def value_of(self, kind: SourceKind, applied_only: bool = False, where: str | None = None) -> int | None:
        """The first valid value of a source of ``kind`` (and ``where``), else None."""
        for s in self.sources:
            if s.kind == kind and s.valid and (not applied_only or s.applied_by_viewers) and \
                    (where is None or s.where == where):
                return s.value
        return None

    def conflicts(self) -> list[str]:
        """One line per disagreement: the valid values different sources state."""
        valid = [s for s in self.sources if s.valid]
        if len({s.value for s in valid}) <= 1:
            return []
        listing = ", ".join(f"{s.kind} ({s.where}) = {s.value}" for s in valid)
        return [f"the file's orientation sources disagree: {listing}"]


def _source(kind: SourceKind, where: str, value: int | None, applied: bool = True,
            detail: str | None = None) -> OrientationSource:
    return OrientationSource(kind=kind, where=where, value=value, valid=value in VALID_ORIENTATIONS,
                             applied_by_viewers=applied, detail=detail)


def inspect(data: bytes, header: ImageHeader, sidecars: dict[str, bytes] | None = None) -> Inspection:
    """Every orientation ``data`` (a photo whose header is ``header``) and its ``sidecars`` (name -> bytes)
    state. Never raises for damaged metadata: an unreadable place is a source with a ``detail``."""
    fmt = header.format
    sources: list[OrientationSource] = []
    exif: ExifInfo | None = None
    heif: HeifInfo | None = None
    packet: bytes | None = None
    span: tuple[int, int] | None = None
    bigtiff = False
    if fmt in ("jpeg", "webp"):
        exif = read_exif(data, header)
        span = _jpeg_xmp_span(data, header) if fmt == "jpeg" else _riff_span(data, b"XMP ")
        where = "Exif APP1 segment, IFD0" if fmt == "jpeg" else "EXIF chunk, IFD0"
    elif fmt == "tiff":
        exif, span = _tiff_state(data, header.ifd0)
        where = "TIFF IFD0"
    elif fmt == "png":
        exif, packet, text_exif = _png_state(data)
        where = "eXIf chunk, IFD0"
        if text_exif is not None:
            sources.append(_source("exif-ifd0", "PNG text chunk 'Raw profile type exif' (ImageMagick)",
                                   text_exif.orientation, applied=False, detail=text_exif.detail or None))
    elif fmt in ("heif", "avif"):
        heif, heif_exif, packet = _heif_state(data)
        sources.append(_source("heif-transform", "irot/imir of the primary image",
                               heif_orientation(heif.transforms) if heif is not None else None))
        if heif_exif is not None:
            sources.append(_source("heif-exif", "EXIF item, IFD0 (ignored by HEIF readers)", heif_exif, applied=False))
        where = ""
    else:  # raw
        exif, span = _raw_state(data)
        where = "RAW IFD0"
    if span is not None:
        packet = data[span[0]:span[1]]
    if exif is not None and (exif.orientation is not None or exif.status == "unreadable"):
        sources.insert(0, _source("exif-ifd0", where, exif.orientation, detail=exif.detail or None))
    xmp_value = None
    if packet is not None:
        state = read_packet(packet)
        if state.status != "absent":
            sources.append(_source("xmp-embedded", "XMP packet in the file", state.value,
                                   applied=fmt not in ("heif", "avif"), detail=state.detail or None))
            xmp_value = state.value
    found: dict[str, XmpOrientation] = {}
    for name, text in (sidecars or {}).items():
        state = read_packet(text)
        found[name] = state
        if state.status != "absent":
            sources.append(_source("xmp-sidecar", name, state.value, detail=state.detail or None))
    if fmt == "tiff" and data[:4] in (b"II+\x00", b"MM\x00+"):
        bigtiff = True
    return Inspection(fmt, sources, exif, heif, xmp_value, found, bigtiff, header, span)


# --- reading, per format ---------------------------------------------------------------------------

def _jpeg_xmp_span(data: bytes, header: ImageHeader) -> tuple[int, int] | None:
    """Where the packet of the JPEG's XMP APP1 segment lies, if it has one."""
    for seg in header.segments:
        if seg.marker == 0xE1 and data[seg.payload].startswith(XMP_JPEG_HEADER):
            return seg.payload.start + len(XMP_JPEG_HEADER), seg.end
    return None


def _riff_span(data: bytes, fourcc: bytes) -> tuple[int, int] | None:
    """Where the data of the first ``fourcc`` chunk of a RIFF file lies, if it has one."""
    return next(((s, e) for f, s, e in riff_chunks(data) if f == fourcc), None)


def _tiff_state(data: bytes, ifd0: Ifd0 | None = None) -> tuple[ExifInfo, tuple[int, int] | None]:
    """(the Orientation state of a TIFF structure's IFD0, where its XMP packet lies); ``ifd0``: its IFD0, when
    already read."""
    try:
        ifd0 = read_ifd0(data) if ifd0 is None else ifd0
    except ValueError as exc:
        return ExifInfo("unreadable", detail=str(exc)), None
    endian, tags = ifd0.endian, ifd0.tags
    span = None
    if _XMP_TIFF_TAG in tags:
        ftype, count, raw = tags[_XMP_TIFF_TAG]
        if ftype in (1, 7) and count > 4:
            offset = struct.unpack_from(endian + "I", raw)[0]
            if offset + count <= len(data):
                span = (offset, offset + count)
    if ORIENTATION_TAG not in tags:
        return ExifInfo("ok"), span
    values = tiff_values(data, endian, tags[ORIENTATION_TAG])
    if not values:
        return ExifInfo("unreadable", detail="the Orientation entry is not a SHORT"), span
    return ExifInfo("ok", values[0]), span


def png_chunks(data: bytes):
    """(type, start of chunk, start of data, end of data) of each chunk up to IEND."""
    pos = 8
    while pos + 12 <= len(data):
        length, kind = struct.unpack_from(">I4s", data, pos)
        yield kind, pos, pos + 8, pos + 8 + length
        if kind == b"IEND":
            return
        pos += 12 + length


def _png_state(data: bytes) -> tuple[ExifInfo, bytes | None, ExifInfo | None]:
    exif = ExifInfo("absent")
    packet = text_exif = None
    for kind, _, s, e in png_chunks(data):
        body = data[s:e]
        if kind == b"eXIf":
            tiff = body[6:] if body.startswith(b"Exif\x00\x00") else body
            exif = tiff_block_state(tiff)
        elif kind == b"iTXt" and body.startswith(_PNG_XMP_KEY + b"\x00"):
            packet = _itxt_text(body)
        elif kind in (b"tEXt", b"zTXt") and body.startswith(_PNG_RAW_EXIF_KEY + b"\x00"):
            text_exif = _raw_profile_exif(kind, body)
    return exif, packet, text_exif


def _itxt_text(body: bytes) -> bytes | None:
    """The text of an iTXt chunk (keyword, flags, language, translated keyword, text)."""
    try:
        key_end = body.index(b"\x00")
        compressed = body[key_end + 1]
        rest = body[key_end + 3:]
        rest = rest[rest.index(b"\x00") + 1:]
        rest = rest[rest.index(b"\x00") + 1:]
        return zlib.decompress(rest) if compressed else rest
    except (ValueError, IndexError, zlib.error):
        return None


def _raw_profile_exif(kind: bytes, body: bytes) -> ExifInfo:
    """ImageMagick's hex-encoded EXIF in a PNG text chunk ("\\nexif\\n  <length>\\n<hex>")."""
    try:
        text = body[len(_PNG_RAW_EXIF_KEY) + 1:]
        if kind == b"zTXt":
            text = zlib.decompress(text[1:])
        parts = text.decode("latin-1").strip().split("\n", 2)
        raw = bytes.fromhex(re.sub(r"\s+", "", parts[2]))
    except (ValueError, IndexError, zlib.error) as exc:
        return ExifInfo("unreadable", detail=f"the text chunk's EXIF cannot be decoded ({exc})")
    tiff = raw[raw.find(b"Exif\x00\x00") + 6:] if b"Exif\x00\x00" in raw[:16] else raw
    return tiff_block_state(tiff)


def _heif_state(data: bytes) -> tuple[HeifInfo | None, int | None, bytes | None]:
    try:
        info = read_heif(data)
    except (BoxError, struct.error, IndexError):
        return None, None, None
    exif_value = packet = None
    if info.kind == "heif":
        import pillow_heif

        try:
            heif = pillow_heif.open_heif(io.BytesIO(data), convert_hdr_to_8bit=True)
            raw_exif = heif.info.get("exif")
            packet = heif.info.get("xmp")
        except (ValueError, RuntimeError, OSError):
            raw_exif = None
        if raw_exif:
            tiff = raw_exif[6:] if raw_exif.startswith(b"Exif\x00\x00") else raw_exif
            exif_value = tiff_block_state(tiff).orientation
    else:
        from PIL import Image

        try:
            with Image.open(io.BytesIO(data)) as im:
                packet = im.info.get("xmp")  # Pillow's AVIF "exif" is partly made up from irot/imir: not read
        except (OSError, ValueError):
            packet = None
    if isinstance(packet, str):
        packet = packet.encode("utf-8")
    return info, exif_value, packet


def _raw_state(data: bytes) -> tuple[ExifInfo, tuple[int, int] | None]:
    if data[:4] in (b"II*\x00", b"MM\x00*"):
        return _tiff_state(data)
    with tempfile.TemporaryDirectory(prefix="sweepcast-raw-") as tmp:
        path = Path(tmp) / "photo.raw"
        path.write_bytes(data)
        out = exiftool.run(["-n", "-s3", "-IFD0:Orientation", "-EXIF:Orientation", str(path)]).stdout.decode()
    first = out.strip().splitlines()[0] if out.strip() else ""
    return (ExifInfo("ok", int(first)) if first.isdigit() else ExifInfo("absent")), None


# --- writing ---------------------------------------------------------------------------------------

def target_for(fmt: ImageFormat, mode: WriteMode, insp: Inspection | None = None) -> tuple[Target, str | None]:
    """(target, note) for writing into a ``fmt`` photo in ``mode``."""
    if mode == "sidecar":
        return "xmp-sidecar", "sidecar asked for: the photo is left untouched"
    if insp is not None and insp.bigtiff:
        return "xmp-sidecar", "BigTIFF files are not written here: a sidecar instead"
    target = IN_FILE_TARGET.get(fmt)
    if target is None:
        why = {"heif": "HEIF readers ignore an EXIF tag (irot/imir rule there) and the file is never written",
               "avif": "AVIF readers ignore an EXIF tag (irot/imir rule there) and the file is never written",
               "raw": "RAW files are never written"}[fmt]
        return "xmp-sidecar", f"{why}: a sidecar instead"
    return target, None


def write_in_file(data: bytes, insp: Inspection, value: int) -> tuple[bytes, list[str]]:
    """``data`` with its Orientation set to ``value`` where its format keeps it (and an embedded XMP
    tiff:Orientation set to agree); returns (new bytes, the other places updated). ``insp`` is what
    :func:`inspect` said of these very bytes: its header, EXIF state and packet span are used, not read again.
    Raises UnsupportedImage for formats that take no tag here, ExifToolUnavailable for a PNG without exiftool."""
    fmt = insp.format
    if fmt in ("jpeg", "webp") or (fmt == "tiff" and not insp.bigtiff):
        require_orientation(value)
        out, also = data, []
        # The packet first: it keeps its length, so the header read before still describes the bytes.
        if insp.xmp_value is not None and insp.xmp_value != value and insp.xmp_span is not None:
            out, patched = _patch_embedded(out, insp.xmp_span, value)
            also += ["XMP packet in the file"] if patched else []
        if fmt == "tiff":
            return write_tiff_orientation(out, value, insp.header.ifd0 if insp.header else None), also
        return write_orientation(out, value, insp.header, insp.exif), also
    if fmt == "png":
        return write_png_orientation(data, value, update_xmp=insp.xmp_value is not None), (
            ["XMP packet in the file"] if insp.xmp_value is not None and insp.xmp_value != value else [])
    raise UnsupportedImage(f"{fmt.upper()} files are not written here; an XMP sidecar takes the orientation")


def _patch_embedded(data: bytes, span: tuple[int, int], value: int) -> tuple[bytes, bool]:
    """``data`` with the tiff:Orientation of its embedded XMP packet (at ``span``) patched in place (same length)."""
    new = patch_packet(data[span[0]:span[1]], value)
    if new is None:
        return data, False
    return data[:span[0]] + new + data[span[1]:], True


def write_tiff_orientation(data: bytes, value: int, ifd0: Ifd0 | None = None) -> bytes:
    """A classic TIFF (either byte order, any number of pages) with IFD0's Orientation set to ``value``:
    the two value bytes patched in place when the tag is one SHORT, else a copy of IFD0 with the tag
    appended at the end of the file and the header pointed at it (every other byte, strip and page
    unchanged). ``ifd0``: the file's IFD0, when already read. Raises UnreadableImage when it cannot be read."""
    require_orientation(value)
    try:
        return _set_orientation(data, value, ifd0)
    except ValueError as exc:
        raise UnreadableImage(f"the TIFF's first image directory cannot be read: {exc}") from None


def write_png_orientation(data: bytes, value: int, update_xmp: bool = False) -> bytes:
    """A PNG with its ``eXIf`` chunk (created, or updated and moved before IDAT) holding Orientation
    ``value``, by ExifTool; with ``update_xmp`` the XMP packet's tiff:Orientation too. Every other chunk
    keeps its bytes (ExifTool copies them). Raises ExifToolUnavailable / ExifToolError."""
    with tempfile.TemporaryDirectory(prefix="sweepcast-png-") as tmp:
        src, out = Path(tmp) / "in.png", Path(tmp) / "out.png"
        src.write_bytes(data)
        args = ["-q", "-m", "-n", f"-IFD0:Orientation={value}"]
        if update_xmp:
            args.append(f"-XMP-tiff:Orientation={value}")
        exiftool.run([*args, "-o", str(out), str(src)])
        if not out.is_file():
            raise exiftool.ExifToolError("exiftool wrote no file")
        written = out.read_bytes()
    exif, _, _ = _png_state(written)
    if exif.status == "absent":  # the EXIF lives only in ImageMagick's text chunk, which exiftool updated
        written = _insert_png_exif(written, value)
    return written


def _insert_png_exif(data: bytes, value: int) -> bytes:
    """``data`` with a new ``eXIf`` chunk holding only Orientation ``value``, before the first IDAT
    (browsers read EXIF only from there; ExifTool keeps a PNG's EXIF in the chunk it found it in)."""
    import piexif

    body = piexif.dump({"0th": {ORIENTATION_TAG: value}})[6:]  # the TIFF structure, without "Exif\0\0"
    chunk = struct.pack(">I", len(body)) + b"eXIf" + body + struct.pack(">I", zlib.crc32(b"eXIf" + body))
    idat = next(start for kind, start, _, _ in png_chunks(data) if kind == b"IDAT")
    return data[:idat] + chunk + data[idat:]


def new_sidecar(value: int) -> bytes:
    """A new XMP sidecar holding only ``tiff:Orientation`` = ``value`` (UTF-8, with an xpacket wrapper)."""
    require_orientation(value)
    return _TEMPLATE.format(value=value).encode("utf-8")


def sidecar_for(value: int, existing: bytes | None) -> tuple[bytes, str]:
    """(sidecar bytes with tiff:Orientation = ``value``, the writer used): a new sidecar from our
    template; an existing one patched in place when it holds a value (every other byte kept), else
    given the property by ExifTool (which keeps its other properties)."""
    if existing is None:
        return new_sidecar(value), "sweepcast"
    patched = patch_packet(existing, value)
    if patched is not None:
        return patched, "sweepcast"
    return sidecar_bytes(value, existing), "exiftool"
