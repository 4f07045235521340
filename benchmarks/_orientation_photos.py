"""The dev face photos the orientation benchmarks share, the optional models beside the data, and the photos' turned and
upscaled copies (JPEG bytes, as a client sends them)."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from workers.common.datasets import data_root, dataset
from workers.orientation.geometry import ROTATIONS, rotate_view

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".webp")

NEGATIVES = {"dogs.jpg"}

MEGAPIXELS = 12.0


def dev_photos() -> Path | None:
    """``$SWEEPCAST_DATA/faces/dev`` (the face photos every table uses), None when the data has none."""
    return dataset("faces", "dev")


def yunet_model() -> Path | None:
    """The YuNet model beside the data (``models/yunet``), None when it is not there."""
    path = data_root().parent / "models" / "yunet" / "face_detection_yunet_2023mar.onnx"
    return path if path.is_file() else None


def mcs_cascades() -> Path | None:
    """The paper's own part cascades beside the data (``models/haar_mcs``, CC BY-NC 4.0: benchmark only), or None."""
    path = data_root().parent / "models" / "haar_mcs"
    return path if (path / "haarcascade_mcs_nose.xml").is_file() else None


def find_photos(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)

def load_photo(path: Path, megapixels: float | None = None) -> np.ndarray:
    """The stored pixels of ``path`` (BGR), upscaled (bicubic) to about ``megapixels`` if given."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
    if megapixels is None:
        return image
    s = (megapixels * 1e6 / (image.shape[0] * image.shape[1])) ** 0.5
    return cv2.resize(image, None, fx=s, fy=s, interpolation=cv2.INTER_CUBIC)

def rotated_inputs(path: Path, megapixels: float | None = None, quality: int = 95) -> dict[int, bytes]:
    """The photo turned so that rotating it ``r`` degrees clockwise makes it upright, as JPEG bytes."""
    image = load_photo(path, megapixels)
    out = {}
    for r in ROTATIONS:
        ok, buf = cv2.imencode(".jpg", rotate_view(image, (360 - r) % 360), [cv2.IMWRITE_JPEG_QUALITY, quality])
        assert ok
        out[r] = buf.tobytes()
    return out

def make_large_jpegs(photos: list[Path], count: int) -> list[bytes]:
    """``count`` face photos upscaled to ~12 MP (bicubic) and encoded as JPEG quality 90."""
    faces = [p for p in photos if p.name not in NEGATIVES]
    out = []
    for i in np.linspace(0, len(faces) - 1, min(count, len(faces))).round().astype(int):  # spread over the set
        path = faces[i]
        ok, buf = cv2.imencode(".jpg", load_photo(path, MEGAPIXELS), [cv2.IMWRITE_JPEG_QUALITY, 90])
        assert ok
        out.append(buf.tobytes())
    return out
