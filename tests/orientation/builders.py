"""Inputs the orientation tests build in code: images, JPEG/PNG/WebP bytes, EXIF blocks, a fake detector."""
from __future__ import annotations

import struct
from dataclasses import dataclass, field

import cv2
import numpy as np
import piexif

from harness.photos import asymmetric_image
from workers.orientation import exiftool
from workers.orientation.detect import Face
from workers.orientation.headers import parse_header


def exiftool_runs() -> bool:
    """Whether the exiftool the engine would use runs here (the tests that need it are skipped without)."""
    try:
        exiftool.run(["-ver"])
    except exiftool.ExifToolUnavailable:
        return False
    return True


def encode(image: np.ndarray, ext: str = ".jpg", params: list[int] | None = None) -> bytes:
    ok, buf = cv2.imencode(ext, image, params or [])
    assert ok
    return buf.tobytes()


def jpeg(image: np.ndarray | None = None, quality: int = 95) -> bytes:
    return encode(asymmetric_image() if image is None else image, ".jpg", [cv2.IMWRITE_JPEG_QUALITY, quality])


def insert_app1(jpeg_bytes: bytes, payload: bytes) -> bytes:
    """The JPEG with an APP1 segment holding ``payload`` after SOI and its JFIF APP0 (as cameras do)."""
    first = parse_header(jpeg_bytes).segments[0]
    pos = first.end if first.marker == 0xE0 else 2
    return jpeg_bytes[:pos] + b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload + jpeg_bytes[pos:]


def rich_exif(orientation: int | None = 1) -> bytes:
    """An EXIF block (``Exif\\0\\0`` + TIFF) with tags in IFD0, Exif, GPS, a maker note and a thumbnail."""
    zeroth = {piexif.ImageIFD.Make: b"SweepCam", piexif.ImageIFD.Model: b"X1", piexif.ImageIFD.Software: b"test",
              piexif.ImageIFD.XResolution: (72, 1), piexif.ImageIFD.YResolution: (72, 1),
              piexif.ImageIFD.ResolutionUnit: 2}
    if orientation is not None:
        zeroth[piexif.ImageIFD.Orientation] = orientation
    return piexif.dump({
        "0th": zeroth,
        "Exif": {piexif.ExifIFD.DateTimeOriginal: b"2024:01:02 03:04:05", piexif.ExifIFD.ExposureTime: (1, 125),
                 piexif.ExifIFD.MakerNote: b"\x01\x02maker-note", piexif.ExifIFD.UserComment: b"ASCII\0\0\0hello"},
        "GPS": {piexif.GPSIFD.GPSLatitudeRef: b"N", piexif.GPSIFD.GPSLatitude: ((51, 1), (30, 1), (0, 1))},
        "1st": {piexif.ImageIFD.Compression: 6},
        "thumbnail": jpeg(asymmetric_image(24, 40), 80),
    })


def tiff_block(entries: list[tuple[int, int, int, bytes]], endian: str = "<") -> bytes:
    """``Exif\\0\\0`` + a minimal TIFF whose IFD0 holds ``entries`` (tag, type, count, 4 inline value bytes)."""
    mark = b"II*\x00" if endian == "<" else b"MM\x00*"
    ifd = struct.pack(endian + "H", len(entries))
    ifd += b"".join(struct.pack(endian + "HHI", t, ty, n) + v for t, ty, n, v in sorted(entries))
    return b"Exif\x00\x00" + mark + struct.pack(endian + "I", 8) + ifd + b"\0\0\0\0"


def ifd0_entries(data: bytes) -> dict[int, bytes]:
    """Raw 12-byte IFD0 entries of a JPEG's EXIF block, by tag."""
    seg = next(s for s in parse_header(data).segments if s.marker == 0xE1)
    tiff = data[seg.payload][6:]
    endian = "<" if tiff[:2] == b"II" else ">"
    offset = struct.unpack_from(endian + "I", tiff, 4)[0]
    count = struct.unpack_from(endian + "H", tiff, offset)[0]
    raw = [tiff[offset + 2 + 12 * i:offset + 14 + 12 * i] for i in range(count)]
    return {struct.unpack_from(endian + "H", e)[0]: e for e in raw}


def split_around_app1(data: bytes) -> tuple[bytes, bytes]:
    """The bytes before and after the Exif APP1 segment."""
    seg = next(s for s in parse_header(data).segments if s.marker == 0xE1)
    return data[:seg.start], data[seg.end:]


@dataclass
class FakeDetector:
    """Test double: accepts one face per listed rotation, records the images it was shown."""

    rotations: tuple[int, ...] = ()
    decisive: bool = True
    box: tuple[float, float, float, float] = (10.0, 20.0, 30.0, 40.0)
    name: str = "fake"
    seen: list[tuple[int, ...]] = field(default_factory=list)

    def upright_faces(self, gray: np.ndarray) -> list[Face]:
        self.seen.append(gray.shape)
        return [Face(self.box, r, 0.9, ("eyes",), "yunet", self.decisive) for r in self.rotations]


def avif(image: np.ndarray | None = None, orientation: int | None = None) -> bytes:
    """An AVIF (Pillow's encoder) of ``image`` (BGR); an EXIF orientation becomes its irot/imir."""
    import io

    from PIL import Image

    rgb = cv2.cvtColor(asymmetric_image() if image is None else image, cv2.COLOR_BGR2RGB)
    pil = Image.fromarray(rgb)
    buf = io.BytesIO()
    kwargs = {}
    if orientation is not None:
        exif = Image.Exif()
        exif[274] = orientation
        kwargs["exif"] = exif
    pil.save(buf, "AVIF", quality=90, **kwargs)
    return buf.getvalue()


def xmp_packet(value: int | None, form: str = "attribute", pad: int = 200) -> bytes:
    """An XMP packet (xpacket wrapper, ``pad`` bytes of padding) with tiff:Orientation as an attribute or element."""
    prop = ""
    attr = ""
    if value is not None and form == "attribute":
        attr = f' tiff:Orientation="{value}"'
    elif value is not None:
        prop = f"<tiff:Orientation>{value}</tiff:Orientation>"
    body = (f'<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
            f'<rdf:Description rdf:about="" xmlns:tiff="http://ns.adobe.com/tiff/1.0/" '
            f'xmlns:dc="http://purl.org/dc/elements/1.1/"{attr}>{prop}<dc:format>image/jpeg</dc:format>'
            f'</rdf:Description></rdf:RDF></x:xmpmeta>')
    return ('<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>' + body + " " * pad
            + '<?xpacket end="w"?>').encode()


def insert_xmp(jpeg_bytes: bytes, packet: bytes) -> bytes:
    """The JPEG with an XMP APP1 segment (after its first APPn segment)."""
    return insert_app1(jpeg_bytes, b"http://ns.adobe.com/xap/1.0/\x00" + packet)


def letter_marks(seed: int = 0) -> np.ndarray:
    """(900, 1200) uint8 grey: rows of dark L-shaped marks on a noisy grey ground (hedge corners, brackets, posts
    and their shadows seen from above). No word, but Tesseract's OSD votes for one turn in every view with a
    confidence of about 20, and its OCR reads each mark as a confident "L": the previous text cue decided it."""
    rng = np.random.default_rng(seed)
    image = cv2.GaussianBlur((120 + 30 * rng.standard_normal((900, 1200))).clip(0, 255).astype(np.uint8), (0, 0), 3)
    for row in range(6):
        y, x = 90 + row * 140, 60
        while x < 1080:
            size = int(rng.integers(36, 48))
            stroke = max(5, size // 6)
            cv2.rectangle(image, (x, y), (x + stroke, y + size), 30, -1)
            cv2.rectangle(image, (x, y + size - stroke), (x + size * 2 // 3, y + size), 30, -1)
            x += size + (int(rng.integers(8, 30)) if rng.random() < 0.7 else 80)
    return image
