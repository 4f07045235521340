"""Camera intrinsics: parsing calibration files, checking them against the images, rescaling.

Pixel convention (DESIGN.md): (0, 0) is the centre of the top-left pixel. COLMAP files use the
top-left corner instead, so their principal points are shifted by half a pixel here.
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass

import cv2
import numpy as np

from workers.common.jobctx import JobInputError

_DIST_LENGTHS = (4, 5, 8, 12, 14)


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels plus optional OpenCV distortion coefficients (n,)."""

    fx: float
    fy: float
    cx: float
    cy: float
    dist: np.ndarray | None = None

    @property
    def K(self) -> np.ndarray:
        """The 3x3 matrix, float64."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, s: float) -> "Intrinsics":
        """The intrinsics of the image resized by ``s`` (pixel-centre convention kept)."""
        return Intrinsics(self.fx * s, self.fy * s, (self.cx + 0.5) * s - 0.5, (self.cy + 0.5) * s - 0.5, self.dist)

    def check(self, width: int, height: int) -> None:
        """Raise JobInputError when these intrinsics cannot belong to a width x height image."""
        values = [self.fx, self.fy, self.cx, self.cy]
        if not all(math.isfinite(v) for v in values):
            raise JobInputError("the intrinsics contain NaN or infinity")
        if self.fx <= 0 or self.fy <= 0:
            raise JobInputError(f"focal lengths must be positive (fx={self.fx:g}, fy={self.fy:g})")
        if not 0.2 <= self.fx / self.fy <= 5:
            raise JobInputError(f"fx={self.fx:g} and fy={self.fy:g} differ too much for a real camera")
        size = max(width, height)
        # A field of view between about 3 and 175 degrees.
        if not 0.02 * size <= max(self.fx, self.fy) <= 20 * size:
            raise JobInputError(
                f"focal length {max(self.fx, self.fy):g} px is implausible for a {width}x{height} image "
                f"(expected {0.02 * size:.0f}..{20 * size:.0f} px); were the intrinsics given for another resolution?")
        if not (0 <= self.cx <= width - 1 and 0 <= self.cy <= height - 1):
            raise JobInputError(
                f"principal point ({self.cx:g}, {self.cy:g}) lies outside the {width}x{height} image; "
                "were the intrinsics given for another resolution?")
        if self.dist is not None and not np.all(np.isfinite(self.dist)):
            raise JobInputError("the distortion coefficients contain NaN or infinity")


def from_values(fx: float, fy: float, cx: float, cy: float, dist: list[float] | None = None) -> Intrinsics:
    """Intrinsics from four numbers (pixels) and optional distortion coefficients."""
    return Intrinsics(float(fx), float(fy), float(cx), float(cy), _dist(dist))


def _dist(values) -> np.ndarray | None:
    if values is None:
        return None
    d = np.asarray(values, np.float64).ravel()
    if d.size not in _DIST_LENGTHS:
        raise JobInputError(f"distortion needs {', '.join(map(str, _DIST_LENGTHS))} coefficients, got {d.size}")
    return d if np.any(d != 0) else None


def parse_calibration(text: str | bytes) -> Intrinsics:
    """Intrinsics from the text of a calibration file.

    Accepted: OpenCV FileStorage YAML/XML/JSON with a camera matrix (``camera_matrix``, ``K``,
    ``cameraMatrix`` or ``M``) and optional distortion (``distortion_coefficients``, ``dist_coeffs``,
    ``D``, ``dist``); JSON ``{"fx", "fy", "cx", "cy", "dist"?}`` or ``{"K": [[...]], "dist"?}``;
    a COLMAP cameras.txt line (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV); or plain
    numbers: ``fx fy cx cy`` or the nine entries of K. Raises JobInputError otherwise.
    """
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError:
            raise JobInputError("the calibration file is not text") from None
    text = text.strip()
    if not text:
        raise JobInputError("the calibration file is empty")
    for parser in (_from_json, _from_filestorage, _from_colmap, _from_numbers):
        result = parser(text)
        if result is not None:
            return result
    raise JobInputError(
        "could not read the calibration: expected OpenCV YAML/XML/JSON with a camera matrix, a COLMAP "
        "cameras.txt line, or the numbers 'fx fy cx cy'")


def _from_json(text: str) -> Intrinsics | None:
    try:
        d = json.loads(text)
    except ValueError:
        return None
    if not isinstance(d, dict):
        return None
    dist = d.get("dist", d.get("distortion"))
    try:
        if all(k in d for k in ("fx", "fy", "cx", "cy")):
            return from_values(d["fx"], d["fy"], d["cx"], d["cy"], dist)
        if "K" in d:
            K = np.asarray(d["K"], np.float64).reshape(3, 3)
            return from_values(K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist)
    except (TypeError, ValueError):
        raise JobInputError("the calibration JSON holds non-numeric or misshapen values") from None
    return None


def _from_filestorage(text: str) -> Intrinsics | None:
    if not (text.startswith("%YAML") or text.startswith("<?xml") or "opencv_storage" in text):
        return None
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except cv2.error:
        raise JobInputError("the OpenCV calibration file could not be parsed") from None
    try:
        K = _first_matrix(fs, ("camera_matrix", "K", "cameraMatrix", "M", "intrinsics"))
        if K is None or K.size != 9:
            raise JobInputError("the OpenCV calibration file holds no 3x3 camera matrix")
        K = K.reshape(3, 3)
        dist = _first_matrix(fs, ("distortion_coefficients", "dist_coeffs", "distCoeffs", "D", "dist"))
        return from_values(K[0, 0], K[1, 1], K[0, 2], K[1, 2], None if dist is None else dist.ravel())
    finally:
        fs.release()


def _first_matrix(fs: cv2.FileStorage, names: tuple[str, ...]) -> np.ndarray | None:
    for name in names:
        node = fs.getNode(name)
        if not node.empty():
            m = node.mat()
            if m is not None:
                return np.asarray(m, np.float64)
    return None


_COLMAP = {
    # model -> indices of (fx, fy, cx, cy) in its params, then distortion as OpenCV k1 k2 p1 p2
    "SIMPLE_PINHOLE": ((0, 0, 1, 2), lambda p: None),
    "PINHOLE": ((0, 1, 2, 3), lambda p: None),
    "SIMPLE_RADIAL": ((0, 0, 1, 2), lambda p: [p[3], 0, 0, 0]),
    "RADIAL": ((0, 0, 1, 2), lambda p: [p[3], p[4], 0, 0]),
    "OPENCV": ((0, 1, 2, 3), lambda p: p[4:8]),
}


def _from_colmap(text: str) -> Intrinsics | None:
    for line in text.splitlines():
        parts = line.split()
        if not parts or parts[0].startswith("#") or len(parts) < 5 or parts[1] not in _COLMAP:
            continue
        (ifx, ify, icx, icy), dist = _COLMAP[parts[1]]
        try:
            p = [float(v) for v in parts[4:]]
            # COLMAP measures from the image corner: its pixel centres sit at +0.5.
            return from_values(p[ifx], p[ify], p[icx] - 0.5, p[icy] - 0.5, dist(p))
        except (ValueError, IndexError):
            raise JobInputError(f"the COLMAP camera line has too few or non-numeric parameters: {line!r}") from None
    return None


def _from_numbers(text: str) -> Intrinsics | None:
    tokens = [t for t in re.split(r"[\s,;\[\]]+", text) if t]
    try:
        values = [float(t) for t in tokens]
    except ValueError:
        return None
    if len(values) == 4:
        return from_values(*values)
    if len(values) == 9:
        K = np.asarray(values).reshape(3, 3)
        return from_values(K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    return None
