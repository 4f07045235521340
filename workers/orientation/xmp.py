"""XMP ``tiff:Orientation``: read it from a packet (a sidecar file, or the packet embedded in a photo),
set it in an embedded packet without moving a byte, and write sidecars (through ExifTool).

The value has the EXIF Orientation meaning (1-8, relative to the stored pixels). It is written
either as an attribute (``<rdf:Description tiff:Orientation="6">``) or as an element
(``<tiff:Orientation>6</tiff:Orientation>``); both are read. Packets are parsed with defusedxml
(no entity expansion, no external references): a sidecar is user data.

Sidecar names: ``photo.jpg.xmp`` (digiKam, darktable, Immich and PhotoPrism read it; the default)
or ``photo.xmp`` (Lightroom / Camera Raw; Immich and PhotoPrism read it too).

Embedded packets are patched in place (:func:`patch_packet`): the one or two ASCII digits of an
existing value are replaced by the new digit and the packet is padded or trimmed in its trailing
whitespace to its old length, so the JPEG segment, TIFF tag or WebP chunk keeps its size and every
other byte of the file. ExifTool re-serialises the whole packet (and, for TIFF, the whole file);
``benchmarks/orientation_writers.py`` (section orientation_writers) measures both.
"""
from __future__ import annotations

import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Literal
from xml.etree.ElementTree import Element

from defusedxml import ElementTree as SafeET
from defusedxml.common import DefusedXmlException

from workers.orientation import exiftool
from workers.orientation.exif import require_orientation

TIFF_NS = "http://ns.adobe.com/tiff/1.0/"
RDF_NS = "http://www.w3.org/1999/02/22-rdf-syntax-ns#"
_TAG = f"{{{TIFF_NS}}}Orientation"
SidecarNaming = Literal["ext", "stem"]
"""``ext``: ``photo.jpg.xmp`` (default); ``stem``: ``photo.xmp``."""
_UMASK = os.umask(0)
os.umask(_UMASK)  # read once at import; new sidecars get the permissions a plain open() would give
MAX_SIDECAR_BYTES = 4 * 1024 * 1024
"""A larger .xmp file is not read (no real sidecar comes near it)."""

# An existing value: attribute form tiff:Orientation="6" / '6', or element form <tiff:Orientation>6<.
# Any prefix bound to the tiff namespace is accepted (checked against the parsed packet).
_ATTR = re.compile(rb"""(?P<pre>\b(?P<prefix>[A-Za-z_][\w.-]*):Orientation\s*=\s*(?P<q>["']))\s*(?P<val>\d{1,2})\s*(?P=q)""")
_ELEM = re.compile(rb"""(?P<pre><(?P<prefix>[A-Za-z_][\w.-]*):Orientation(?:\s[^>]*)?>)\s*(?P<val>\d{1,2})\s*</(?P=prefix):Orientation\s*>""")


@dataclass(frozen=True)
class XmpOrientation:
    """What an XMP packet says about orientation."""

    status: Literal["ok", "absent", "unreadable"]
    value: int | None = None
    """The tiff:Orientation number as stored (it may be invalid, e.g. 0); None when absent."""
    detail: str = ""


def read_packet(packet: bytes | str) -> XmpOrientation:
    """The ``tiff:Orientation`` of an XMP packet or sidecar text."""
    if isinstance(packet, str):
        packet = packet.encode("utf-8")
    root = _parse(packet)
    if isinstance(root, str):
        return XmpOrientation("unreadable", detail=root)
    values = [v for v in _values(root) if v is not None]
    if not values:
        return XmpOrientation("absent")
    raw = values[0].strip()
    if not raw.isdigit():
        return XmpOrientation("unreadable", detail=f"tiff:Orientation is not a number: {raw[:20]!r}")
    return XmpOrientation("ok", int(raw))


def _parse(packet: bytes) -> Element | str:
    """The packet's XML root, or a message saying why it cannot be read."""
    text = packet.strip(b"\x00 \t\r\n")
    start = text.find(b"<x:xmpmeta")
    if start < 0:
        start = text.find(b"<rdf:RDF")
    if start < 0:
        return "no x:xmpmeta or rdf:RDF element"
    end_meta = text.rfind(b"</x:xmpmeta>")
    end = end_meta + len(b"</x:xmpmeta>") if end_meta >= 0 else text.rfind(b"</rdf:RDF>") + len(b"</rdf:RDF>")
    try:
        return SafeET.fromstring(text[start:end])
    except (SafeET.ParseError, DefusedXmlException, ValueError) as exc:
        return f"the XMP is not well-formed XML ({exc})"


def _values(root: Element) -> list[str | None]:
    out: list[str | None] = []
    for desc in root.iter(f"{{{RDF_NS}}}Description"):
        if _TAG in desc.attrib:
            out.append(desc.attrib[_TAG])
        for child in desc.findall(_TAG):
            out.append(child.text or "")
    return out


def patch_packet(packet: bytes, value: int) -> bytes | None:
    """``packet`` with its one existing ``tiff:Orientation`` set to ``value`` (1-8) and the same length,
    every other byte kept; None when that cannot be done safely (no value, several, an unreadable packet,
    or no trailing whitespace to absorb a shorter/longer number)."""
    require_orientation(value)
    root = _parse(packet)
    if isinstance(root, str) or len([v for v in _values(root) if v is not None]) != 1:
        return None
    matches = [m for rx in (_ATTR, _ELEM) for m in rx.finditer(packet)
               if _is_tiff_prefix(packet, m.group("prefix"))]
    if len(matches) != 1:
        return None
    m = matches[0]
    new = packet[:m.start("val")] + str(value).encode() + packet[m.end("val"):]
    grow = len(new) - len(packet)
    if grow:
        new = _keep_length(new, -grow)
        if new is None:
            return None
    check = read_packet(new)
    return new if check.status == "ok" and check.value == value else None


def _is_tiff_prefix(packet: bytes, prefix: bytes) -> bool:
    return re.search(rb"xmlns:" + re.escape(prefix) + rb"""\s*=\s*["']""" + re.escape(TIFF_NS.encode()),
                     packet) is not None


def _keep_length(packet: bytes, delta: int) -> bytes | None:
    """``packet`` with ``delta`` spaces added (> 0) or removed (< 0) in the padding before ``<?xpacket end``."""
    end = packet.rfind(b"<?xpacket end")
    if end < 0:
        return None
    if delta > 0:
        return packet[:end] + b" " * delta + packet[end:]
    pad = len(packet[:end]) - len(packet[:end].rstrip(b" \t\r\n"))
    if pad < -delta:
        return None
    return packet[:end + delta] + packet[end:]


# --- sidecars ----------------------------------------------------------------------------------------

def sidecar_path(photo: Path, naming: SidecarNaming = "ext") -> Path:
    """Where the sidecar of ``photo`` goes: ``photo.jpg.xmp`` (``ext``) or ``photo.xmp`` (``stem``)."""
    return photo.with_name(photo.name + ".xmp") if naming == "ext" else photo.with_suffix(".xmp")


def sidecar_name(filename: str, naming: SidecarNaming = "ext") -> str:
    """The sidecar file name for an uploaded ``filename`` (its last path component)."""
    base = re.split(r"[\\/]", filename)[-1] or "photo"
    return sidecar_path(Path(base), naming).name


def existing_sidecars(photo: Path) -> list[Path]:
    """The sidecars of ``photo`` that exist, ``photo.jpg.xmp`` first, then ``photo.xmp`` (matched
    case-insensitively on the .xmp suffix, as organisers do)."""
    found = []
    for candidate in (sidecar_path(photo, "ext"), sidecar_path(photo, "stem")):
        for suffix in (".xmp", ".XMP"):
            path = candidate.with_name(candidate.name[:-4] + suffix)
            if path.is_file() and path not in found and path != photo:
                found.append(path)
                break
    return found


def sidecar_bytes(value: int, existing: bytes | None = None) -> bytes:
    """A sidecar's bytes with ``tiff:Orientation`` = ``value``: ``existing`` (a sidecar's text) with the
    value set and all else kept by ExifTool, or a new minimal sidecar. Raises ExifToolUnavailable /
    ExifToolError."""
    require_orientation(value)
    with tempfile.TemporaryDirectory(prefix="sweepcast-xmp-") as tmp:
        out = Path(tmp) / "out.xmp"
        args = ["-q", "-m", "-n", f"-XMP-tiff:Orientation={value}", "-o", str(out)]
        if existing is not None:
            src = Path(tmp) / "in.xmp"
            src.write_bytes(existing)
            args.append(str(src))
        exiftool.run(args)
        if not out.is_file():
            raise exiftool.ExifToolError("exiftool wrote no sidecar")
        return out.read_bytes()


def replace_file(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder, then ``os.replace``),
    keeping an existing file's permissions."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, path.stat().st_mode & 0o7777 if path.exists() else 0o666 & ~_UMASK)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
