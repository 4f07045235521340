"""The four in-plane rotations and the mapping of boxes between a rotated view and the image.

A rotation is given in clockwise degrees, 0, 90, 180 or 270: view ``r`` of an image is the image
turned ``r`` degrees clockwise, so a face found upright in view ``r`` means the stored image must
be turned ``r`` degrees clockwise to be displayed upright (the paper's "0, 90 counter-clockwise,
180, 90 clockwise" are views 0, 270, 180 and 90). Boxes are ``(x, y, w, h)`` in continuous pixel
coordinates, the box covering ``[x, x+w) x [y, y+h)``.
"""
from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

ROTATIONS: tuple[int, ...] = (0, 90, 180, 270)
_CV_ROTATE = {90: cv2.ROTATE_90_CLOCKWISE, 180: cv2.ROTATE_180, 270: cv2.ROTATE_90_COUNTERCLOCKWISE}

Box = tuple[float, float, float, float]


def rotate_view(image: np.ndarray, rotation: int) -> np.ndarray:
    """``image`` (H, W[, C]) turned ``rotation`` degrees clockwise (a lossless pixel permutation)."""
    if rotation == 0:
        return image
    return cv2.rotate(image, _CV_ROTATE[rotation])


class TurnedViews(dict):
    """The views of ``image`` (H, W[, C]) by rotation (0, 90, 180, 270 degrees clockwise), each turned the first time
    it is asked for (``views[90]``): a photo's faces are checked in one or two of them, and turning all three costs
    1-3 ms for a 1-3 MP grey image (a face photo's whole analysis is ~13 ms)."""

    def __init__(self, image: np.ndarray) -> None:
        super().__init__()
        self.image = image

    def __missing__(self, rotation: int) -> np.ndarray:
        view = self[rotation] = rotate_view(self.image, rotation)
        return view


def view_points_to_image(points: np.ndarray, rotation: int, width: int, height: int) -> np.ndarray:
    """Points (N, 2) float in view ``rotation`` -> the same points in the image of size ``width`` x ``height``."""
    u, v = points[:, 0], points[:, 1]
    if rotation == 0:
        return np.stack([u, v], axis=1)
    if rotation == 90:
        return np.stack([v, height - u], axis=1)
    if rotation == 180:
        return np.stack([width - u, height - v], axis=1)
    if rotation == 270:
        return np.stack([width - v, u], axis=1)
    raise ValueError(f"rotation must be one of {ROTATIONS}, not {rotation}")


def view_box_to_image(box: Sequence[float], rotation: int, width: int, height: int) -> Box:
    """Box ``(x, y, w, h)`` in view ``rotation`` -> the box covering the same pixels in the image."""
    x, y, w, h = (float(v) for v in box[:4])
    corners = view_points_to_image(np.array([[x, y], [x + w, y + h]]), rotation, width, height)
    x0, y0 = corners.min(axis=0)
    x1, y1 = corners.max(axis=0)
    return float(x0), float(y0), float(x1 - x0), float(y1 - y0)


def image_box_to_view(box: Sequence[float], rotation: int, width: int, height: int) -> Box:
    """Box ``(x, y, w, h)`` in the image of size ``width`` x ``height`` -> the box covering the same pixels in view
    ``rotation`` (the inverse of :func:`view_box_to_image`)."""
    view_w, view_h = (height, width) if rotation in (90, 270) else (width, height)
    return view_box_to_image(box, (360 - rotation) % 360, view_w, view_h)


def iou(a: Box, b: Box) -> float:
    """Intersection over union of two boxes (0 when disjoint)."""
    iw = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    ih = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    inter = iw * ih
    union = a[2] * a[3] + b[2] * b[3] - inter
    return inter / union if union > 0 else 0.0


# --- the eight EXIF orientations as pixel operations ------------------------------------------------
# Orientation v says how the stored pixels are shown: 1 as stored, 2 mirrored left-right, 3 turned 180,
# 4 mirrored top-bottom, 5 transposed (mirrored about the top-left/bottom-right diagonal), 6 turned 90
# degrees clockwise, 7 transversed (mirrored about the other diagonal), 8 turned 90 counter-clockwise.
_ORIENT_OPS = {
    1: lambda a: a,
    2: lambda a: a[:, ::-1],
    3: lambda a: a[::-1, ::-1],
    4: lambda a: a[::-1, :],
    5: lambda a: a.swapaxes(0, 1),
    6: lambda a: np.rot90(a, -1),
    7: lambda a: a[::-1, ::-1].swapaxes(0, 1),
    8: lambda a: np.rot90(a, 1),
}
_PROBE = np.arange(6).reshape(2, 3)  # every one of the eight operations gives a different array


def apply_orientation(image: np.ndarray, value: int) -> np.ndarray:
    """``image`` (H, W[, C]) as a viewer shows it under EXIF Orientation ``value`` (1-8); a view, not a copy."""
    try:
        return _ORIENT_OPS[value](image)
    except KeyError:
        raise ValueError(f"EXIF Orientation must be 1-8, not {value}") from None


def _orientation_of(result: np.ndarray) -> int:
    return next(v for v, op in _ORIENT_OPS.items() if op(_PROBE).shape == result.shape
                and np.array_equal(op(_PROBE), result))


def turn_orientation(value: int, rotation: int) -> int:
    """The Orientation that shows the stored pixels as Orientation ``value`` does, then turned ``rotation``
    degrees clockwise (0, 90, 180, 270): how a turn found on the *displayed* image becomes a tag for
    the stored one."""
    if rotation not in ROTATIONS:
        raise ValueError(f"rotation must be one of {ROTATIONS}, not {rotation}")
    return _orientation_of(np.rot90(apply_orientation(_PROBE, value), -rotation // 90))


def heif_orientation(transforms: Sequence[tuple[str, int]]) -> int:
    """The EXIF Orientation equal to HEIF/AVIF display transforms applied in order: ("irot", quarter turns
    counter-clockwise 0-3) and ("imir", axis: 0 top-bottom flip, 1 left-right flip, as libheif reads it)."""
    a = _PROBE
    for kind, arg in transforms:
        if kind == "irot":
            a = np.rot90(a, arg % 4)
        elif kind == "imir":
            a = a[::-1, :] if arg == 0 else a[:, ::-1]
        else:
            raise ValueError(f"unknown HEIF transform {kind!r}")
    return _orientation_of(a)
