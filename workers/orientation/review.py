"""A person's decision on a photo the engine left for review: its thumbnail, and writing the orientation they chose.

The batch job makes a small thumbnail of every photo that needs a person (:func:`needs_review`): its stored pixels
(EXIF ignored, as the detector saw them), so a page can show the four turns side by side without loading the
photo. When the person picks a turn, :func:`write_choice` writes it with the engine's own lossless writers: the
photo's tag (JPEG, WebP, TIFF: EXIF IFD0 patched in place; PNG: eXIf), or an XMP sidecar (HEIF, AVIF, RAW, or a
batch that asked for sidecars). The image data is never re-encoded.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from workers.common.errors import InputError
from workers.orientation.decode import DEFAULT_MAX_PIXELS, decode_gray
from workers.orientation.exif import orientation_for_rotation
from workers.orientation.geometry import turn_orientation
from workers.orientation.headers import parse_header, sniff_format
from workers.orientation.metadata import Target, WriteMode, inspect, sidecar_for, target_for, write_in_file
from workers.orientation.xmp import sidecar_name

THUMBNAIL_SIDE = 320
"""Long side (px) of a review thumbnail (JPEG quality ``THUMBNAIL_QUALITY``: a few tens of KB, so a large batch's
page loads a few megabytes, not every photo)."""
THUMBNAIL_QUALITY = 85
REVIEWER_MAX = 80


def needs_review(report: dict[str, Any] | None) -> bool:
    """Whether a batch entry's report (an ``OrientationReport`` as JSON) needs a person: rejected (no cue, cues
    that conflict, or one not clear enough), or places in the file that state different orientations."""
    return report is not None and (bool(report.get("needs_review")) or bool(report.get("conflicts")))


def thumbnail(data: bytes, filename: str | None = None, max_pixels: int = DEFAULT_MAX_PIXELS,
              side: int = THUMBNAIL_SIDE) -> bytes:
    """A JPEG at most ``side`` px long of the pixels the detector analysed: the stored pixels in colour where
    OpenCV decodes the format (JPEG, PNG, WebP, TIFF; EXIF ignored; a JPEG at the smallest DCT scale still at
    least ``side`` px long, so a 12 MP photo is decoded at 1/8 and not in full), else the engine's own grey decode
    (HEIF/AVIF as displayed, RAW's preview). Call it on a photo already analysed (its size was checked then)."""
    buffer = np.frombuffer(data, np.uint8)
    image = None
    fmt = sniff_format(data, filename)
    if fmt in ("jpeg", "png", "webp", "tiff"):
        flags = _colour_flags(data, filename, side) if fmt == "jpeg" else cv2.IMREAD_COLOR
        image = cv2.imdecode(buffer, flags | cv2.IMREAD_IGNORE_ORIENTATION)
    if image is None:
        image = decode_gray(data, max_pixels, side * 2, filename=filename, working_pixels=None).gray
    s = min(1.0, side / max(image.shape[:2]))
    if s < 1.0:
        image = cv2.resize(image, (max(1, round(image.shape[1] * s)), max(1, round(image.shape[0] * s))),
                           interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, THUMBNAIL_QUALITY])
    if not ok:  # pragma: no cover - OpenCV encodes any 8-bit image
        raise ValueError("could not encode the thumbnail")
    return buf.tobytes()


_REDUCED_COLOUR = {8: cv2.IMREAD_REDUCED_COLOR_8, 4: cv2.IMREAD_REDUCED_COLOR_4, 2: cv2.IMREAD_REDUCED_COLOR_2}


def _colour_flags(data: bytes, filename: str | None, side: int) -> int:
    """The colour decode flag of a JPEG whose long side (from its header) is at least ``side`` px at that scale."""
    try:
        header = parse_header(data, filename)
    except InputError:  # the full decode below says what is wrong, as before
        return cv2.IMREAD_COLOR
    long_side = max(header.width or 0, header.height or 0)
    factor = next((f for f in (8, 4, 2) if -(-long_side // f) >= side), 1)
    return _REDUCED_COLOUR.get(factor, cv2.IMREAD_COLOR)


class ReviewChoice(BaseModel):
    """What a person decided for one photo of a batch."""

    model_config = ConfigDict(extra="forbid")

    rotation_degrees: Literal[0, 90, 180, 270] | None = Field(
        description="clockwise turn that shows the photo (as stored, EXIF ignored: as its thumbnail) upright; null: "
                    "leave it as it is (nothing is written)")
    reviewer: str = Field(min_length=1, max_length=REVIEWER_MAX, pattern=r"\S",
                          description="who decided (a name or initials), recorded in the job's report")


@dataclass(frozen=True)
class ChoiceWrite:
    """What writing a person's choice produced."""

    orientation: int
    """The Orientation value written (1-8)."""
    target: Target
    photo: bytes | None = None
    """The photo's new bytes (in-file targets)."""
    sidecar: bytes | None = None
    """The sidecar's bytes (``xmp-sidecar``)."""
    sidecar_name: str | None = None


def write_choice(data: bytes, rotation: int, filename: str | None, mode: WriteMode = "file") -> ChoiceWrite:
    """Write ``rotation`` (clockwise degrees that show the analysed image upright) into ``data`` or its sidecar, with
    the engine's lossless writers, whatever orientation the file states now (a person looked at it). Raises
    InputError subclasses for files that cannot take it, ExifToolUnavailable where a PNG needs ExifTool."""
    header = parse_header(data, filename)
    insp = inspect(data, header)
    if header.format in ("heif", "avif"):  # the analysed image is the displayed one
        value = turn_orientation(insp.shown() or 1, rotation)
    else:
        value = orientation_for_rotation(rotation)
    target, _ = target_for(header.format, mode, insp)
    if target == "xmp-sidecar":
        name = sidecar_name(filename or "photo", "ext")
        return ChoiceWrite(value, target, sidecar=sidecar_for(value, None)[0], sidecar_name=name)
    photo, _ = write_in_file(data, insp, value)
    return ChoiceWrite(value, target, photo=photo)
