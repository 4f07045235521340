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
from workers.orientation.detect import (Decision, DecisionKind, DetectorConfig, Engine, Face, OrientationDetector,
                                        decide, get_detector)
from workers.orientation.exif import (TAGGABLE_FORMATS, ExifInfo, orientation_for_rotation, read_exif,
                                      require_taggable, write_orientation)
from workers.orientation.headers import sniff_format
from workers.orientation.text import TEXT_MAX_SIDE, RejectReason, TextResult

__all__ = ["DetectorConfig", "FaceReport", "OrientationReport", "TextReport", "analyze", "engine_status", "get_detector",
           "orient_jpeg", "plan_tag"]

VALID_ORIENTATIONS = range(1, 9)
"""The eight values EXIF defines for Orientation (274)."""
Action = Literal["analysis_only", "written", "kept_existing", "already_set", "not_written_rejected"]
Cue = Literal["faces", "text", "none"]
TextStatus = Literal["ran", "not_needed", "unavailable", "off"]


class FaceReport(BaseModel):
    """One face accepted as upright in one of the four views."""

    box: list[int] = Field(description="[x, y, width, height] in pixels of the stored image (EXIF ignored)")
    rotation_degrees: int = Field(description="clockwise rotation that makes this face upright")
    score: float | None = Field(description="YuNet confidence; null for a Haar face")
    parts: list[str] = Field(description="facial parts found in an upright arrangement")
    source: Literal["haar", "yunet"]
    decisive: bool = Field(description="false: the face votes for its rotation but cannot decide the photo alone "
                                       "(YuNet's best view by too small a margin, parts not confirmed)")


class TextViewReport(BaseModel):
    """Tesseract's orientation and script detection (OSD) on one view of the photo."""

    view_degrees: int = Field(description="clockwise degrees the stored image was turned for this view")
    ran: bool = Field(description="false: OSD did not run on this view (too few characters, an error)")
    rotation_degrees: int | None = Field(description="clockwise rotation of the stored image this view votes for")
    confidence: float = Field(description="OSD's orientation confidence (0 when it did not run)")
    script: str | None = Field(description="the script OSD recognised (Latin, Han, Arabic, ...)")
    detail: str | None = Field(None, description="why OSD did not run")


class TextReport(BaseModel):
    """The text cue (second stage, used when the faces decide nothing)."""

    status: TextStatus = Field(description="ran; not_needed (the faces decided); unavailable (tesseract or its osd "
                                           "data is not installed: faces only); off (switched off)")
    rotation_degrees: int | None = Field(None, description="clockwise rotation the text decided; null when it "
                                                           "decided nothing")
    reject_reason: RejectReason | None = Field(None, description="why the text decided nothing, when it ran")
    views: list[TextViewReport] = Field(default_factory=list, description="OSD on each of the four views")
    detail: str | None = Field(None, description="why the text cue is unavailable")


class OrientationReport(BaseModel):
    """Which way is up in a photo, and what was done to its EXIF Orientation tag."""

    decision: DecisionKind = Field(description="upright, rotated, or rejected (no cue, conflicting cues, or a cue "
                                               "not clear enough: see reject_reason)")
    orientation: int | None = Field(description="EXIF Orientation for the detected rotation (1, 6, 3, 8); "
                                                "null when rejected")
    rotation_degrees: int | None = Field(description="clockwise rotation that shows the stored pixels upright; "
                                                     "null when rejected")
    accepted_rotations: list[int] = Field(description="the views (clockwise degrees) in which a face was accepted")
    faces: list[FaceReport]
    cue: Cue = Field(description="what decided: faces (the paper's detector), text (Tesseract OSD, when the faces "
                                 "decided nothing), or none (rejected)")
    needs_review: bool = Field(description="true when rejected: a person has to say which way is up")
    reject_reason: RejectReason | None = Field(description="why it was rejected: no_cue (no face and no readable "
                                                           "text), conflicting_rotations (faces or text views, or "
                                                           "faces and text, disagree), low_confidence (a cue "
                                                           "pointed one way but not clearly enough); null when "
                                                           "decided")
    text: TextReport = Field(description="the text cue")
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
    rotation, cue, reason = decision.rotation, ("faces" if decision.rotation is not None else "none"), decision.reason
    text = _text_report_unused(detector)
    engine = detector if isinstance(detector, Engine) else None
    if rotation is None and engine is not None and engine.text is not None:
        result = engine.text.upright(decode_gray(image_bytes, max_pixels, TEXT_MAX_SIDE).gray)
        text = _text_report(result)
        rotation, cue, reason = combine_cues(decision, result)
    header = decoded.header
    exif = read_exif(image_bytes, header) if header.format in TAGGABLE_FORMATS else None
    tag, detail = _valid_tag(exif)
    return OrientationReport(
        decision=_kind(rotation),
        orientation=None if rotation is None else orientation_for_rotation(rotation),
        rotation_degrees=rotation,
        accepted_rotations=list(decision.accepted_rotations),
        faces=[_face_report(f, decoded.scale_x, decoded.scale_y) for f in _ordered(faces)],
        cue=cue,
        needs_review=rotation is None,
        reject_reason=reason,
        text=text,
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
        message=_describe(decision, faces, text, rotation, cue, reason),
        elapsed_ms=_ms_since(start),
    )


def _kind(rotation: int | None) -> DecisionKind:
    if rotation is None:
        return "rejected"
    return "upright" if rotation == 0 else "rotated"


_REASON_RANK = {"conflicting_rotations": 2, "low_confidence": 1, "no_cue": 0}


def combine_cues(faces: Decision, text: TextResult) -> tuple[int | None, Cue, RejectReason | None]:
    """Faces decided nothing: (rotation, cue, reason) with the text's result. The text decides only when
    no face was accepted, or faces only in the text's own view (not decisive alone): a face accepted in
    any other view is a conflict, and so are faces accepted in several views even if one of them is the
    text's. A rejection keeps the more telling of the two reasons (conflict, then low confidence, then
    no cue)."""
    if text.rotation is not None:
        if faces.accepted_rotations and set(faces.accepted_rotations) != {text.rotation}:
            return None, "none", "conflicting_rotations"
        return text.rotation, "text", None
    reasons = [r for r in (faces.reason, text.reason) if r is not None]
    return None, "none", max(reasons, key=_REASON_RANK.__getitem__) if reasons else "no_cue"


def _text_report_unused(detector: OrientationDetector) -> TextReport:
    """The text report of a photo whose text was not read: not needed, unavailable or off."""
    info = detector.text_info if isinstance(detector, Engine) else {"enabled": False, "detail": "faces only"}
    if not info.get("enabled"):
        return TextReport(status="off", detail=str(info.get("detail")) if info.get("detail") else None)
    if not info.get("available"):
        return TextReport(status="unavailable", detail=str(info.get("detail")))
    return TextReport(status="not_needed")


def _text_report(result: TextResult) -> TextReport:
    return TextReport(
        status="ran", rotation_degrees=result.rotation, reject_reason=result.reason,
        views=[TextViewReport(view_degrees=v.view, ran=v.ran, rotation_degrees=v.rotation,
                              confidence=round(v.confidence, 2), script=v.script, detail=v.detail)
               for v in result.views])


def engine_status(config: DetectorConfig) -> dict[str, object]:
    """What the orientation engine of ``config`` uses, for the readiness report: the face detector (and its
    YuNet model) and the text cue (tesseract, or why not: faces only). Never raises."""
    out: dict[str, object] = {"ok": True, "yunet_model": str(config.yunet_model) if config.yunet_model else None}
    try:
        engine = get_detector(config)
        out["faces"] = engine.name
        out["text"] = engine.text_info
    except (ValueError, OSError) as exc:
        out["faces"] = None
        out["detail"] = str(exc)
    return out


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


def _describe(decision: Decision, faces: list[Face], text: TextReport, rotation: int | None, cue: Cue,
              reason: RejectReason | None) -> str:
    if cue == "text" and rotation is not None:
        agreeing = sum(v.ran and v.rotation_degrees == rotation for v in text.views)
        what = f"text read upright by Tesseract OSD in {agreeing} of 4 views (no decisive face)"
        if rotation == 0:
            return f"upright as stored: {what}"
        return (f"rotated: turn {rotation} deg clockwise to show it upright "
                f"(EXIF {orientation_for_rotation(rotation)}); {what}")
    if text.status == "ran":
        faces_part = _describe(decision, faces, TextReport(status="not_needed"), None, "none", decision.reason)
        if text.rotation_degrees is not None:
            return (f"{faces_part}; the text points to {text.rotation_degrees} deg, which conflicts with the faces "
                    "(needs review)")
        why = {"no_cue": "no readable text", "conflicting_rotations": "the text's views disagree",
               "low_confidence": "the text's orientation is not clear enough"}[text.reject_reason or "no_cue"]
        return f"{faces_part}; {why} (needs review)"
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
