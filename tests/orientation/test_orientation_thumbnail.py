"""The review thumbnail of a large photo: made from a reduced decode, the same picture as from the full one."""
from __future__ import annotations

import cv2
import numpy as np

from harness.photos import asymmetric_image
from workers.orientation.review import THUMBNAIL_SIDE, thumbnail


def _large_photo(width: int = 4000, height: int = 3000) -> np.ndarray:
    small = asymmetric_image(120, 160)  # colour, and different under every turn: a grey or turned thumbnail is off
    return cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)


def _decoded(data: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR).astype(np.float32)


def test_a_large_jpeg_s_thumbnail_is_the_photo_small_and_in_colour():
    photo = _large_photo()
    data = cv2.imencode(".jpg", photo, [cv2.IMWRITE_JPEG_QUALITY, 92])[1].tobytes()
    thumb = _decoded(thumbnail(data, "big.jpg"))
    assert thumb.shape == (THUMBNAIL_SIDE * 3 // 4, THUMBNAIL_SIDE, 3)
    reference = cv2.resize(photo, (thumb.shape[1], thumb.shape[0]), interpolation=cv2.INTER_AREA).astype(np.float32)
    assert float(np.mean(np.abs(thumb - reference))) < 6.0  # JPEG twice over; a wrong turn or crop is far off


def test_a_jpeg_smaller_than_the_thumbnail_keeps_its_size():
    photo = _large_photo(300, 200)
    data = cv2.imencode(".jpg", photo, [cv2.IMWRITE_JPEG_QUALITY, 92])[1].tobytes()
    assert _decoded(thumbnail(data, "small.jpg")).shape == (200, 300, 3)
