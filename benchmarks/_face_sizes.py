"""Faces of every size: the dev face photos rescaled and padded so that one face spans a given share of the photo's
short side (issue 33: the Haar scan size must be checked on faces small to large, not tuned to the dev photos).

Each photo's subject is its largest YuNet face on the upright photo (photos without one are left out). For each
share in ``FACE_SHARES`` the photo is scaled so that this face is that share of ``CANVAS``'s short side and cut to
``CANVAS`` around the face (its edge pixels repeated where the scaled photo is smaller: a mirrored border would add upside-down faces): a 2048 x 1365 photo, the size
of the photo whose 280 px face the 320 px scan lost. A photo is never enlarged more than ``MAX_UPSCALE`` times (an
enlarged small face is blurrier than a real one of that size): those variants are left out.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

CANVAS = (1365, 2048)
"""(height, width) of every variant."""
FACE_SHARES = (0.05, 0.08, 0.11, 0.15, 0.2, 0.3, 0.45)
"""Face width as a share of the canvas's short side (68 to 614 px)."""
MAX_UPSCALE = 3.0


def subject_box(image: np.ndarray, yunet: Path) -> tuple[float, float, float, float] | None:
    """(x, y, w, h) of the largest face YuNet finds in ``image`` (BGR, upright), or None."""
    s = min(1.0, 640 / max(image.shape[:2]))
    small = cv2.resize(image, None, fx=s, fy=s, interpolation=cv2.INTER_AREA) if s < 1 else image
    net = cv2.FaceDetectorYN.create(str(yunet), "", (small.shape[1], small.shape[0]), 0.8, 0.3, 5000)
    _, rows = net.detect(small)
    if rows is None:
        return None
    x, y, w, h = max(rows, key=lambda r: r[2] * r[3])[:4]
    return x / s, y / s, w / s, h / s


def variant(image: np.ndarray, box: tuple[float, float, float, float], share: float) -> np.ndarray | None:
    """``image`` scaled so that ``box``'s width is ``share`` of the canvas's short side, cut to the canvas around the
    face; None when that would enlarge it more than ``MAX_UPSCALE`` times."""
    height, width = CANVAS
    k = share * min(CANVAS) / box[2]
    if k > MAX_UPSCALE:
        return None
    scaled = cv2.resize(image, None, fx=k, fy=k, interpolation=cv2.INTER_AREA if k < 1 else cv2.INTER_CUBIC)
    cx, cy = (box[0] + box[2] / 2) * k, (box[1] + box[3] / 2) * k
    x0, y0 = int(round(cx - width / 2)), int(round(cy - height / 2))
    pad = (max(0, -y0), max(0, y0 + height - scaled.shape[0]), max(0, -x0), max(0, x0 + width - scaled.shape[1]))
    if any(pad):
        scaled = cv2.copyMakeBorder(scaled, *pad, cv2.BORDER_REPLICATE)
        x0, y0 = x0 + pad[2], y0 + pad[0]
    return np.ascontiguousarray(scaled[y0:y0 + height, x0:x0 + width])


def face_size_set(photos: list[Path], yunet: Path) -> Iterator[tuple[str, float, np.ndarray]]:
    """(photo name, face share, BGR canvas) for every photo with a face and every share it allows."""
    for path in photos:
        image = cv2.imread(str(path), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
        box = subject_box(image, yunet) if image is not None else None
        if box is None:
            continue
        for share in FACE_SHARES:
            out = variant(image, box, share)
            if out is not None:
                yield path.name, share, out
