"""Photos built in code for the tests and benchmarks: JPEGs without a face (the job system needs none), an image
that differs under every turn and mirror, and TIFFs of several pages."""
from __future__ import annotations

import struct

import cv2
import numpy as np

FACES_ONLY = {"text": "false"}
"""Form fields of a photo batch without the text cue: the job-system tests' photos have no face, and reading
them for text (1-3 s of CPU each) would only make those tests slow."""


def noise_jpeg(seed: int, width: int = 640, height: int = 480, quality: int = 85) -> bytes:
    """A JPEG of smooth random blobs: decodes fine, has no face (the detector rejects it)."""
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, (height // 16 + 1, width // 16 + 1, 3), dtype=np.uint8)
    image = cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return buf.tobytes()


def batch_files(n: int, corrupt_at: int | None = None, **kwargs) -> list[tuple[str, tuple[str, bytes, str]]]:
    """Multipart ``files`` fields for a batch upload; ``corrupt_at`` gets a truncated JPEG."""
    files = []
    for i in range(n):
        data = noise_jpeg(i, **kwargs)
        if i == corrupt_at:
            data = data[: len(data) // 3]
        files.append(("files", (f"photo {i}.jpg", data, "image/jpeg")))
    return files


def gradient_jpeg(width: int = 640, height: int = 480) -> bytes:
    """A JPEG of a smooth colour gradient: nothing a face detector could take for a face."""
    x = np.linspace(0, 255, width, dtype=np.float32)[None, :, None]
    y = np.linspace(0, 255, height, dtype=np.float32)[:, None, None]
    image = np.concatenate([x + 0 * y, y + 0 * x, (x + y) / 2], axis=2).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", image)
    assert ok
    return buf.tobytes()


def asymmetric_image(height: int = 120, width: int = 200) -> np.ndarray:
    """(H, W, 3) uint8 BGR that looks different under every rotation and mirror."""
    x = np.linspace(0, 200, width, dtype=np.float32)
    image = np.repeat(np.repeat(x[None, :, None], height, 0), 3, 2).astype(np.uint8)
    cv2.rectangle(image, (width // 10, height // 10), (width // 3, height // 3), (255, 255, 255), -1)
    cv2.circle(image, (3 * width // 4, 3 * height // 4), min(height, width) // 8, (0, 0, 255), -1)
    cv2.line(image, (0, height // 2), (width // 2, height - 1), (0, 255, 0), max(2, height // 40))
    return image


def tiff(pages: list[np.ndarray], endian: str = "<", orientation: int | None = None,
         orientation_type: int = 3) -> bytes:
    """An uncompressed greyscale TIFF of one or more pages ((H, W) uint8 each), little- or big-endian,
    with IFD0's Orientation (274) when given (as ``orientation_type``: 3 SHORT, 4 LONG)."""
    mark = b"II*\x00" if endian == "<" else b"MM\x00*"
    out = bytearray(mark + b"\0\0\0\0")
    ifd_offsets = []
    for page in pages:
        height, width = page.shape
        strip = len(out)
        out += page.tobytes()
        if len(out) & 1:
            out += b"\0"
        entries = [(256, 4, 1, width), (257, 4, 1, height), (258, 3, 1, 8), (259, 3, 1, 1), (262, 3, 1, 1),
                   (273, 4, 1, strip), (277, 3, 1, 1), (278, 4, 1, height), (279, 4, 1, width * height)]
        if orientation is not None and not ifd_offsets:
            entries.append((274, orientation_type, 1, orientation))
        entries.sort()
        ifd_offsets.append(len(out))
        out += struct.pack(endian + "H", len(entries))
        for tag, ftype, count, value in entries:
            packed = struct.pack(endian + "H", value) + b"\0\0" if ftype == 3 else struct.pack(endian + "I", value)
            out += struct.pack(endian + "HHI", tag, ftype, count) + packed
        out += b"\0\0\0\0"  # next IFD, patched below
    struct.pack_into(endian + "I", out, 4, ifd_offsets[0])
    for here, nxt in zip(ifd_offsets, ifd_offsets[1:]):
        count = struct.unpack_from(endian + "H", out, here)[0]
        struct.pack_into(endian + "I", out, here + 2 + 12 * count, nxt)
    return bytes(out)


def gray_pages(n: int = 3, height: int = 30, width: int = 40) -> list[np.ndarray]:
    """``n`` different asymmetric grey pages."""
    base = cv2.cvtColor(asymmetric_image(height, width), cv2.COLOR_BGR2GRAY)
    return [np.ascontiguousarray(np.roll(base, 7 * i, axis=1)) for i in range(n)]
