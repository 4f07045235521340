"""What the web layer, the batch job and the CLI call: analyse a photo, tag a JPEG.

    detector = get_detector(DetectorConfig(yunet_model=...))   # once per process
    report = analyze(data, detector, max_pixels)                 # any JPEG/PNG/WebP
    new_bytes, report = orient_jpeg(data, detector, force, max_pixels)

Both raise :class:`workers.orientation.errors.OrientationInputError` subclasses for bad input.
"""
from __future__ import annotations

import time
from typing import Literal

from pydantic import BaseModel, Field

from workers.orientation.decode import DEFAULT_MAX_PIXELS, decode_gray
from workers.orientation.detect import (Decision, DecisionKind, DetectorConfig, Face, OrientationDetector, decide,
                                        get_detector)
from workers.orientation.exif import (TAGGABLE_FORMATS, ExifInfo, orientation_for_rotation, read_exif,
                                      require_taggable, write_orientation)
from workers.orientation.headers import sniff_format

__all__ = ["DetectorConfig", "FaceReport", "OrientationReport", "analyze", "get_detector", "orient_jpeg", "plan_tag"]

VALID_ORIENTATIONS = range(1, 9)
"""The eight values EXIF defines for Orientation (274)."""
Action = Literal["analysis_only", "written", "kept_existing", "already_set", "not_written_rejected"]


class FaceReport(BaseModel):
    """One face accepted as upright in one of the four views."""

    box: list[int] = Field(description="[x, y, width, height] in pixels of the stored image (EXIF ignored)")
    rotation_degrees: int = Field(description="clockwise rotation that makes this face upright")
    score: float | None = Field(description="YuNet confidence; null for a Haar face")
    parts: list[str] = Field(description="facial parts found in an upright arrangement")
    source: Literal["haar", "yunet"]
    decisive: bool = Field(description="false: the face votes for its rotation but cannot decide the photo alone "
                                       "(YuNet's best view by too small a margin, parts not confirmed)")


class OrientationReport(BaseModel):
    """Which way is up in a photo, and what was done to its EXIF Orientation tag."""

    decision: DecisionKind = Field(description="upright, rotated, or rejected (no face or conflicting faces)")
    orientation: int | None = Field(description="EXIF Orientation for the detected rotation (1, 6, 3, 8); "
                                                "null when rejected")
    rotation_degrees: int | None = Field(description="clockwise rotation that shows the stored pixels upright; "
                                                     "null when rejected")
    accepted_rotations: list[int] = Field(description="the views (clockwise degrees) in which a face was accepted")
    faces: list[FaceReport]
    width: int = Field(description="stored image width (px)")
    height: int = Field(description="stored image height (px)")
    format: Literal["jpeg", "png", "webp"]
    detector: str = Field(description="detector configuration used: paper, yunet or combined")
    existing_orientation: int | None = Field(description="Orientation tag found in the file, if any and valid (1-8)")
    exif_status: Literal["absent", "ok", "unreadable", "not_applicable"]
    exif_detail: str | None = Field(None, description="why the EXIF block is unreadable, or that its Orientation "
                                                      "value is invalid (not 1-8) and treated as absent")
    action: Action = Field(description="what happened to the file")
    written: bool = Field(description="whether a new Orientation tag was written")
    written_orientation: int | None = Field(description="the value written, when written")
    file_orientation: int | None = Field(description="the Orientation tag the returned file carries (null: none, "
                                                     "or not readable)")
    message: str = Field(description="a one-line summary for people")
    elapsed_ms: float = Field(description="decode + detection (+ writing) time")


def analyze(image_bytes: bytes, detector: OrientationDetector,
            max_pixels: int = DEFAULT_MAX_PIXELS) -> OrientationReport:
    """Detect the upright rotation of a JPEG, PNG or WebP photo (its stored pixels)."""
    start = time.perf_counter()
    decoded = decode_gray(image_bytes, max_pixels)
    faces = detector.upright_faces(decoded.gray)
    decision = decide(faces)
    header = decoded.header
    exif = read_exif(image_bytes, header) if header.format in TAGGABLE_FORMATS else None
    tag, detail = _valid_tag(exif)
    return OrientationReport(
        decision=decision.kind,
        orientation=None if decision.rotation is None else orientation_for_rotation(decision.rotation),
        rotation_degrees=decision.rotation,
        accepted_rotations=list(decision.accepted_rotations),
        faces=[_face_report(f, decoded.scale_x, decoded.scale_y) for f in _ordered(faces)],
        width=header.width,
        height=header.height,
        format=header.format,
        detector=detector.name,
        existing_orientation=tag,
        exif_status=exif.status if exif is not None else "not_applicable",
        exif_detail=detail,
        action="analysis_only",
        written=False,
        written_orientation=None,
        file_orientation=tag,
        message=_describe(decision, faces),
        elapsed_ms=_ms_since(start),
    )


def _valid_tag(exif: ExifInfo | None) -> tuple[int | None, str | None]:
    """(the file's Orientation tag when it is one of the eight valid values, else None; the EXIF detail).

    A stored value outside 1..8 means nothing to a viewer: it is reported as absent, with the
    detail saying so, and never echoed (a client would trust it as a tag in ``X-Orientation``).
    """
    if exif is None:
        return None, None
    detail = exif.detail or None
    if exif.orientation is not None and exif.orientation not in VALID_ORIENTATIONS:
        note = f"the stored Orientation value {exif.orientation} is not valid (1-8): treated as absent"
        return None, f"{detail}; {note}" if detail else note
    return exif.orientation, detail


def orient_jpeg(jpeg_bytes: bytes, detector: OrientationDetector, force: bool = False,
                max_pixels: int = DEFAULT_MAX_PIXELS) -> tuple[bytes, OrientationReport]:
    """Detect the upright rotation of a JPEG (or WebP) and set its EXIF Orientation losslessly.

    Returns the new file bytes (the input itself when nothing is written) and the report. A tag
    other than 1 already in the file is kept unless ``force``; a rejected photo is never tagged;
    an unreadable EXIF block is replaced by a valid one (``exif_status`` says so). PNG and other
    formats raise UnsupportedFormat before any decoding.
    """
    start = time.perf_counter()
    require_taggable(sniff_format(jpeg_bytes))
    report = analyze(jpeg_bytes, detector, max_pixels)
    action, value = plan_tag(report, force)
    out = write_orientation(jpeg_bytes, value) if action == "written" else jpeg_bytes
    report = report.model_copy(update={
        "action": action,
        "written": action == "written",
        "written_orientation": value if action == "written" else None,
        "file_orientation": value if action == "written" else report.file_orientation,
        "message": f"{report.message}; {_ACTION_TEXT[action]}",
        "elapsed_ms": _ms_since(start),
    })
    return out, report


_ACTION_TEXT: dict[str, str] = {
    "written": "Orientation tag written",
    "kept_existing": "the file's own Orientation tag was kept (use force to replace it)",
    "already_set": "the file already shows it upright; nothing written",
    "not_written_rejected": "nothing written",
}


def plan_tag(report: OrientationReport, force: bool) -> tuple[Action, int | None]:
    """What :func:`orient_jpeg` does with the tag after ``report`` (an :func:`analyze` report):
    (action, value to write or None)."""
    if report.orientation is None:
        return "not_written_rejected", None
    existing = report.existing_orientation if report.existing_orientation in VALID_ORIENTATIONS else None
    if existing is not None and existing != 1 and not force:
        return "kept_existing", None
    # What viewers show now: the tag, 1 without EXIF, unknown for an invalid or unreadable tag.
    shown = existing if existing is not None else (1 if report.exif_status == "absent" else None)
    if shown == report.orientation:
        return "already_set", None
    return "written", report.orientation


def _ordered(faces: list[Face]) -> list[Face]:
    return sorted(faces, key=lambda f: (f.rotation, -(f.score or 0.0), f.box))


def _face_report(face: Face, sx: float, sy: float) -> FaceReport:
    x, y, w, h = face.box
    box = [round(x * sx), round(y * sy), round(w * sx), round(h * sy)]
    return FaceReport(box=box, rotation_degrees=face.rotation, score=None if face.score is None else round(face.score, 4),
                      parts=list(face.parts), source=face.source, decisive=face.decisive)


def _describe(decision: Decision, faces: list[Face]) -> str:
    if decision.rotation is None:
        if not decision.accepted_rotations:
            return "rejected: no face was accepted in any of the four rotations"
        views = ", ".join(f"{r} deg" for r in decision.accepted_rotations)
        if len(decision.accepted_rotations) == 1:
            return f"rejected: the faces found upright at {views} are not clear enough to decide"
        return f"rejected: faces were accepted in {len(decision.accepted_rotations)} rotations ({views})"
    n = len(faces)
    what = f"{n} face{'s' if n != 1 else ''} accepted in one rotation"
    if decision.rotation == 0:
        return f"upright as stored: {what}"
    return (f"rotated: turn {decision.rotation} deg clockwise to show it upright "
            f"(EXIF {orientation_for_rotation(decision.rotation)}); {what}")


def _ms_since(start: float) -> float:
    return round((time.perf_counter() - start) * 1000.0, 2)
