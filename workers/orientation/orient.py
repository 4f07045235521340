"""What the web layer, the batch job and the CLI call: analyse a photo, write its orientation.

    detector = get_detector(DetectorConfig(yunet_model=...))   # once per process
    report = analyze(data, detector, max_pixels, filename="a.heic")   # any format; says what it would write where
    outcome = orient_file(data, detector, force, max_pixels, filename="a.tif", mode="file")  # bytes to store

They raise :class:`workers.orientation.errors.OrientationInputError` subclasses for bad input, and
:class:`workers.orientation.exiftool.ExifToolUnavailable` when a write needs exiftool and it is missing.

Orientation values are relative to the *stored* pixels (EXIF meaning; HEIF/AVIF: the coded image),
while ``rotation_degrees`` is the clockwise turn found on the image the detector saw: the stored
pixels, except for HEIF/AVIF, whose displayed image (irot/imir applied) is analysed.
"""
from __future__ import annotations

import time
from typing import Literal

from pydantic import BaseModel, Field

from workers.orientation.decode import DEFAULT_MAX_PIXELS, decode_gray
from workers.orientation.detect import (Decision, DecisionKind, DetectorConfig, Engine, Face, OrientationDetector,
                                        decide, get_detector)
from workers.orientation.exif import VALID_ORIENTATIONS, ExifInfo, orientation_for_rotation
from workers.orientation.geometry import turn_orientation
from workers.orientation.headers import ImageFormat, parse_header
from workers.orientation.metadata import (Inspection, OrientationSource, WriteMode, WritePlan, inspect, sidecar_for,
                                          target_for, write_in_file)
from workers.orientation.xmp import SidecarNaming, sidecar_name
from workers.orientation.text import TEXT_MAX_SIDE, RejectReason, TextResult

__all__ = ["DetectorConfig", "FaceReport", "OrientOutcome", "OrientationReport", "TextReport", "analyze",
           "engine_status", "get_detector", "orient_file", "plan_write"]

Action = Literal["analysis_only", "written", "kept_existing", "already_set", "not_written_rejected"]
Cue = Literal["faces", "text", "none"]
TextStatus = Literal["ran", "not_needed", "unavailable", "off"]


class FaceReport(BaseModel):
    """One face accepted as upright in one of the four views."""

    box: list[int] = Field(description="[x, y, width, height] in pixels of the stored image (EXIF ignored; "
                                       "HEIF/AVIF: of the displayed image)")
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
    orientation: int | None = Field(description="EXIF Orientation (1-8) that shows the stored pixels upright: 1, 6, "
                                                "3, 8 for the detected rotation; for HEIF/AVIF the turn found on "
                                                "the displayed image combined with the file's irot/imir (it may "
                                                "then be a mirrored value); null when rejected")
    rotation_degrees: int | None = Field(description="clockwise rotation that shows the analysed image upright "
                                                     "(the stored pixels; HEIF/AVIF: the displayed image); "
                                                     "null when rejected")
    accepted_rotations: list[int] = Field(description="the views (clockwise degrees) in which a face was accepted")
    faces: list[FaceReport]
    cue: Cue = Field(description="what decided: faces (the paper's detector), text (Tesseract OSD, when the faces "
                                 "decided nothing), or none (rejected)")
    needs_review: bool = Field(description="true when rejected: a person has to say which way is up")
    confidence: float | None = Field(None, description="how clear the deciding cue was: the best YuNet score of the "
                                                       "decisive faces (0-1; null for the paper's Haar faces), or the "
                                                       "mean Tesseract OSD confidence of the agreeing text views; "
                                                       "null when rejected")
    reject_reason: RejectReason | None = Field(description="why it was rejected: no_cue (no face and no readable "
                                                           "text), conflicting_rotations (faces or text views, or "
                                                           "faces and text, disagree), low_confidence (a cue "
                                                           "pointed one way but not clearly enough); null when "
                                                           "decided")
    text: TextReport = Field(description="the text cue")
    width: int = Field(description="stored image width (px)")
    height: int = Field(description="stored image height (px)")
    format: ImageFormat = Field(description="jpeg, png, webp, tiff, heif, avif or raw (RAW: its embedded preview "
                                            "is analysed; width/height are the preview's)")
    detector: str = Field(description="detector configuration used: paper, yunet or combined")
    existing_orientation: int | None = Field(description="the orientation viewers apply now, if valid (1-8): the "
                                                         "EXIF tag (else the embedded XMP); HEIF/AVIF: irot/imir "
                                                         "(1 when none)")
    exif_status: Literal["absent", "ok", "unreadable", "not_applicable"]
    exif_detail: str | None = Field(None, description="why the EXIF block is unreadable, or that its Orientation "
                                                      "value is invalid (not 1-8) and treated as absent")
    sources: list[OrientationSource] = Field(default_factory=list, description="every place in or beside the file "
                                                                            "that states an orientation")
    conflicts: list[str] = Field(default_factory=list, description="disagreements between those places (EXIF "
                                                                   "IFD0, embedded XMP, sidecars, irot/imir)")
    write: WritePlan | None = Field(None, description="what writing does (or, in an analysis, would do) and where")
    action: Action = Field(description="what happened to the file")
    written: bool = Field(description="whether a new Orientation tag was written")
    written_orientation: int | None = Field(description="the value written, when written")
    file_orientation: int | None = Field(description="the Orientation tag the returned file carries (null: none, "
                                                     "or not readable)")
    message: str = Field(description="a one-line summary for people")
    elapsed_ms: float = Field(description="decode + detection (+ writing) time")


def analyze(image_bytes: bytes, detector: OrientationDetector, max_pixels: int = DEFAULT_MAX_PIXELS,
            filename: str | None = None, sidecars: dict[str, bytes] | None = None, mode: WriteMode = "file",
            naming: SidecarNaming = "ext", force: bool = False, *,
            inspection: Inspection | None = None) -> OrientationReport:
    """Detect the upright rotation of a photo in any supported format and say what writing it would do.

    ``filename`` tells TIFF-based RAW files from TIFFs and names the sidecar; ``sidecars`` (name -> bytes)
    are the XMP files beside the photo; ``mode``, ``naming`` and ``force`` shape the plan in ``write``;
    ``inspection``: what :func:`inspect` said of the photo and these sidecars, when the caller has it."""
    return _analyze(image_bytes, detector, max_pixels, filename, sidecars, mode, naming, force, inspection)[0]


def _analyze(image_bytes: bytes, detector: OrientationDetector, max_pixels: int, filename: str | None,
             sidecars: dict[str, bytes] | None, mode: WriteMode, naming: SidecarNaming, force: bool,
             inspection: Inspection | None) -> tuple[OrientationReport, Inspection, Action, int | None]:
    """(the :func:`analyze` report, the photo's inspection, the action and value its plan writes): the header
    parsed once, the metadata read once, for the report and the write."""
    start = time.perf_counter()
    parsed = inspection.header if inspection is not None else None
    if parsed is None:
        parsed = parse_header(image_bytes, filename)
    decoded = decode_gray(image_bytes, max_pixels, filename=filename, header=parsed)
    faces = detector.upright_faces(decoded.gray)
    decision = decide(faces)
    rotation, cue, reason = decision.rotation, ("faces" if decision.rotation is not None else "none"), decision.reason
    text = _text_not_read(detector)
    text_result: TextResult | None = None
    engine = detector if isinstance(detector, Engine) else None
    if rotation is None and engine is not None and engine.text is not None:
        text_result = engine.text.upright(decode_gray(image_bytes, max_pixels, TEXT_MAX_SIDE, filename=filename,
                                                      header=parsed).gray)
        text = _text_report(text_result)
        rotation, cue, reason = combine_cues(decision, text_result)
    header = decoded.header  # a RAW file's: its preview's size
    insp = inspection if inspection is not None else inspect(image_bytes, parsed, sidecars)
    exif = insp.exif
    tag, detail = _valid_tag(exif)
    shown = insp.shown()
    if rotation is None:
        orientation = None
    elif header.format in ("heif", "avif"):
        orientation = turn_orientation(shown or 1, rotation)
    else:
        orientation = orientation_for_rotation(rotation)
    report = OrientationReport(
        decision=_kind(rotation),
        orientation=orientation,
        rotation_degrees=rotation,
        accepted_rotations=list(decision.accepted_rotations),
        faces=[_face_report(f, decoded.scale_x, decoded.scale_y) for f in _ordered(faces)],
        cue=cue,
        needs_review=rotation is None,
        confidence=_confidence(cue, rotation, faces, text),
        reject_reason=reason,
        text=text,
        width=header.width,
        height=header.height,
        format=header.format,
        detector=detector.name,
        existing_orientation=shown if shown in VALID_ORIENTATIONS else tag,
        exif_status=exif.status if exif is not None else "not_applicable",
        exif_detail=detail,
        sources=insp.sources,
        conflicts=insp.conflicts(),
        action="analysis_only",
        written=False,
        written_orientation=None,
        file_orientation=shown if header.format in ("heif", "avif") else tag,
        message=_describe(decision, faces, text, rotation, cue, reason, text_result),
        elapsed_ms=_ms_since(start),
    )
    action, value, plan = plan_write(report, insp, mode, force, naming, filename)
    return report.model_copy(update={"write": plan}), insp, action, value


def _confidence(cue: Cue, rotation: int | None, faces: list[Face], text: TextReport) -> float | None:
    if rotation is None:
        return None
    if cue == "faces":
        scores = [f.score for f in faces if f.rotation == rotation and f.decisive and f.score is not None]
        return round(max(scores), 4) if scores else None
    votes = [v.confidence for v in text.views if v.ran and v.rotation_degrees == rotation]
    return round(sum(votes) / len(votes), 2) if votes else None


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


def _text_not_read(detector: OrientationDetector) -> TextReport:
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


class OrientOutcome(BaseModel):
    """What :func:`orient_file` produced: the report, and the bytes to store where the plan says."""

    report: OrientationReport
    photo: bytes | None = Field(None, description="the photo's new bytes (in-file targets), when written")
    sidecar: bytes | None = Field(None, description="the sidecar's bytes (xmp-sidecar target), when written")
    sidecar_name: str | None = None
    updated_sidecars: dict[str, bytes] = Field(default_factory=dict, description="existing sidecars brought into "
                                                                                 "agreement (name -> new bytes)")


def orient_file(data: bytes, detector: OrientationDetector, force: bool = False,
                max_pixels: int = DEFAULT_MAX_PIXELS, filename: str | None = None,
                sidecars: dict[str, bytes] | None = None, mode: WriteMode = "file",
                naming: SidecarNaming = "ext", *, inspection: Inspection | None = None) -> OrientOutcome:
    """Detect the upright rotation and produce what writing it takes: the photo's new bytes (JPEG, WebP,
    TIFF, PNG in ``file`` mode), or a sidecar's (HEIF, AVIF, RAW, or ``sidecar`` mode), plus the existing
    ``sidecars`` that must change to agree. Nothing is written to disk here; a rejected photo, a kept
    tag and an orientation already shown produce no bytes. ``inspection``: as for :func:`analyze`."""
    start = time.perf_counter()
    report, insp, action, value = _analyze(data, detector, max_pixels, filename, sidecars, mode, naming, force,
                                           inspection)
    plan = report.write
    outcome = OrientOutcome(report=report)
    if action == "written" and value is not None:
        if plan.target in ("exif-ifd0", "png-exif"):
            outcome.photo, _ = write_in_file(data, insp, value)
        else:
            name = plan.where or sidecar_name(filename or "photo", naming)
            outcome.sidecar, _ = sidecar_for(value, (sidecars or {}).get(name))
            outcome.sidecar_name = name
        for name, text in (sidecars or {}).items():
            state = insp.sidecars.get(name)
            if name != outcome.sidecar_name and state is not None and state.value is not None and state.value != value:
                outcome.updated_sidecars[name], _ = sidecar_for(value, text)
    file_value = value if action == "written" and plan.target != "xmp-sidecar" else report.file_orientation
    outcome.report = report.model_copy(update={
        "action": action,
        "written": action == "written",
        "written_orientation": value if action == "written" else None,
        "file_orientation": file_value,
        "write": plan,
        "message": f"{report.message}; {_ACTION_TEXT[action]}",
        "elapsed_ms": _ms_since(start),
    })
    return outcome


_ACTION_TEXT: dict[str, str] = {
    "written": "orientation written",
    "kept_existing": "the file's own orientation was kept (use force to replace it)",
    "already_set": "the file already shows it upright; nothing written",
    "not_written_rejected": "nothing written",
    "analysis_only": "nothing written",
}


def plan_write(report: OrientationReport, insp: Inspection, mode: WriteMode = "file", force: bool = False,
               naming: SidecarNaming = "ext", filename: str | None = None) -> tuple[Action, int | None, WritePlan]:
    """(action, value, plan) for writing ``report``'s orientation into or beside the photo ``insp`` describes.

    The existing orientation is what the target holds (a sidecar's value, when the target is a sidecar that
    exists), else what viewers show now. Rejected: nothing. An existing valid value other than 1 and other
    than the detected one is kept unless ``force``. Nothing is written when the target already holds the
    detected value and every place that would be written (embedded XMP, existing sidecars) agrees."""
    target, note = target_for(insp.format, mode, insp)
    where = sidecar_name(filename or "photo", naming) if target == "xmp-sidecar" else "the photo"
    writer = "exiftool" if target == "png-exif" else "sweepcast"
    value = report.orientation

    def plan(action: Action, why: str | None = None, also: list[str] | None = None) -> tuple[Action, int | None, WritePlan]:
        written = action == "written"
        return action, value if written else None, WritePlan(
            target=target if written else "none", where=where if written else None,
            value=value if written else None, also=also or [], writer=writer if written else None,
            note="; ".join(n for n in (note, why) if n) or None)

    if value is None:
        return plan("not_written_rejected", "rejected: nothing is written")
    in_sidecar = insp.sidecars.get(where) if target == "xmp-sidecar" else None
    if in_sidecar is not None and in_sidecar.value in VALID_ORIENTATIONS:
        existing = in_sidecar.value
    else:
        existing = insp.shown()
    if existing in VALID_ORIENTATIONS and existing not in (1, value) and not force:
        return plan("kept_existing", f"the existing orientation {existing} is kept (force replaces it)")
    also = []
    if target != "xmp-sidecar" and insp.xmp_value is not None and insp.xmp_value != value:
        also.append("XMP packet in the file")
    also += [name for name, st in insp.sidecars.items()
             if name != where and st.value is not None and st.value != value]
    target_ok = existing == value and (target != "xmp-sidecar" or in_sidecar is None or in_sidecar.value == value)
    if target != "xmp-sidecar":
        target_ok = target_ok and insp.value_of("exif-ifd0", applied_only=True) in (value, None) and not (
            value != 1 and insp.value_of("exif-ifd0", applied_only=True) is None)
    if target_ok and not also:
        return plan("already_set", "the photo already shows it upright")
    return plan("written", None, also)


def _ordered(faces: list[Face]) -> list[Face]:
    return sorted(faces, key=lambda f: (f.rotation, -(f.score or 0.0), f.box))


def _face_report(face: Face, sx: float, sy: float) -> FaceReport:
    x, y, w, h = face.box
    box = [round(x * sx), round(y * sy), round(w * sx), round(h * sy)]
    return FaceReport(box=box, rotation_degrees=face.rotation, score=None if face.score is None else round(face.score, 4),
                      parts=list(face.parts), source=face.source, decisive=face.decisive)


def _describe(decision: Decision, faces: list[Face], text: TextReport, rotation: int | None, cue: Cue,
              reason: RejectReason | None, text_result: TextResult | None = None) -> str:
    if cue == "text" and rotation is not None:
        if text_result is not None:
            what = f"text read upright by Tesseract: {text_result.summary()} (no decisive face)"
        else:
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
        why = {"no_cue": "no readable text", "conflicting_rotations": "the text's views (or OSD and OCR) disagree",
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
