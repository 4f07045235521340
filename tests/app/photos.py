"""Photos the tests generate (no real faces needed for the job system)."""
from __future__ import annotations

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
