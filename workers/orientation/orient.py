"""What the web layer, the batch job and the CLI call: analyse a photo, write its orientation.

    detector = get_detector(DetectorConfig(yunet_model=...))   # once per process
    report = analyze(data, detector, max_pixels, filename="a.heic")   # any format; says what it would write where
    outcome = orient_file(data, detector, force, max_pixels, filename="a.tif", mode="file")  # bytes to store

They raise :class:`~workers.common.errors.InputError` subclasses for bad input, and
:class:`workers.orientation.exiftool.ExifToolUnavailable` when a write needs exiftool and it is missing.

Orientation values are relative to the *stored* pixels (EXIF meaning; HEIF/AVIF: the coded image),
while ``rotation_degrees`` is the clockwise turn found on the image the detector saw: the stored
pixels, except for HEIF/AVIF, whose displayed image (irot/imir applied) is analysed.
"""
from __future__ import annotations

import time
from typing import Literal

import numpy as np
from pydantic import BaseModel, Field

from workers.orientation.decode import DEFAULT_MAX_PIXELS, decode_at_least, decode_gray
from workers.orientation.detect import (Decision, DecisionKind, DetectorConfig, Engine, Face, OrientationDetector,
                                        decide, get_detector)
from workers.orientation.exif import VALID_ORIENTATIONS, ExifInfo, orientation_for_rotation
from workers.orientation.geometry import turn_orientation
from workers.orientation.headers import ImageFormat, check_header, parse_header
from workers.orientation.metadata import (Inspection, OrientationSource, WriteMode, WritePlan, inspect, sidecar_for,
                                          target_for, write_in_file)
from workers.orientation.xmp import SidecarNaming, sidecar_name
from workers.orientation.text import RejectReason, TextResult

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


class TextReadingReport(BaseModel):
    """One reading of the text lines of one axis, one way up."""

    reader: Literal["tesseract", "recognizer", "script"] = Field(
        description="who read: tesseract (English), recognizer (PaddleOCR's PP-OCRv6), script (a Tesseract script "
                    "model, for the script Tesseract's OSD saw)")
    rotation_degrees: int = Field(description="the clockwise rotation of the stored image this reading tests")
    words: int = Field(description="words read (with a letter)")
    real_words: int = Field(description="words a dictionary knows, confident, on lines of one letter size")
    lines: int = Field(description="how many of the lines read hold a real word")
    sample: list[str] = Field(default_factory=list, description="a few of the real words")


class TextReport(BaseModel):
    """The text cue (second stage, used when the faces decide nothing)."""

    status: TextStatus = Field(description="ran; not_needed (the faces decided); unavailable (its models could not be "
                                           "loaded: faces only); off (switched off)")
    rotation_degrees: int | None = Field(None, description="clockwise rotation the text decided; null when it "
                                                           "decided nothing")
    reject_reason: RejectReason | None = Field(None, description="why the text decided nothing, when it ran")
    lines: int = Field(0, description="text lines the text detector found (0: no text, nothing was read)")
    zoomed: bool = Field(False, description="whether the detector looked again, closer, for small print")
    readings: list[TextReadingReport] = Field(default_factory=list, description="the readings of the lines, both "
                                                                                "ways up, in the order they ran")
    script: str | None = Field(None, description="the script Tesseract's OSD saw on the lines, when the script "
                                                 "reader ran")
    detail: str | None = Field(None, description="why the text cue is unavailable")


class OrientationReport(BaseModel):
    """Which way is up in a photo, and what was done to its EXIF Orientation tag."""

    decision: DecisionKind | Literal["not_analysed"] = Field(
        description="upright, rotated, or rejected (no cue, conflicting cues, or a cue not clear enough: see "
                    "reject_reason); not_analysed: a write that keeps the file's own orientation (other than 1; "
                    "force not set) does not analyse the photo")
    orientation: int | None = Field(description="EXIF Orientation (1-8) that shows the stored pixels upright: 1, 6, "
                                                "3, 8 for the detected rotation; for HEIF/AVIF the turn found on "
                                                "the displayed image combined with the file's irot/imir (it may "
                                                "then be a mirrored value); null when rejected")
    rotation_degrees: int | None = Field(description="clockwise rotation that shows the analysed image upright "
                                                     "(the stored pixels; HEIF/AVIF: the displayed image); "
                                                     "null when rejected")
    accepted_rotations: list[int] = Field(description="the views (clockwise degrees) in which a face was accepted")
    faces: list[FaceReport]
    cue: Cue = Field(description="what decided: faces (the paper's detector), text (its lines read both ways up, "
                                 "when the faces decided nothing), or none (rejected)")
    needs_review: bool = Field(description="true when rejected: a person has to say which way is up")
    confidence: float | None = Field(None, description="how clear the deciding cue was: the best YuNet score of the "
                                                       "decisive faces (0-1; null for the paper's Haar faces), or, "
                                                       "for text, the deciding reading's share of the real words "
                                                       "read both ways up (0.5-1); null when rejected")
    reject_reason: RejectReason | None = Field(description="why it was rejected: no_cue (no face and no readable "
                                                           "text), conflicting_rotations (faces in several views, or "
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
             inspection: Inspection | None, skip_kept: bool = False
             ) -> tuple[OrientationReport, Inspection, Action, int | None]:
    """(the :func:`analyze` report, the photo's inspection, the action and value its plan writes): the header
    parsed once, the metadata read once, for the report and the write. ``skip_kept``: a photo whose existing
    orientation a write would keep (:func:`kept_orientation`) is not analysed at all."""
    start = time.perf_counter()
    parsed = inspection.header if inspection is not None else None
    if parsed is None:
        parsed = parse_header(image_bytes, filename)
    if skip_kept and not force:
        insp = inspection if inspection is not None else inspect(image_bytes, parsed, sidecars)
        kept = kept_orientation(insp, mode, naming, filename)
        if kept is not None:
            check_header(parsed, max_pixels)
            return _not_analysed(insp, parsed, kept, detector, mode, naming, filename, start), insp, "kept_existing", None
        inspection = insp
    decoded = decode_gray(image_bytes, max_pixels, filename=filename, header=parsed)
    faces = detector.upright_faces(decoded.gray)
    decision = decide(faces)
    rotation, cue, reason = decision.rotation, ("faces" if decision.rotation is not None else "none"), decision.reason
    text = _text_not_read(detector)
    text_result: TextResult | None = None
    engine = detector if isinstance(detector, Engine) else None
    if rotation is None and engine is not None and engine.text is not None:
        text_result = engine.text.upright(decoded.gray, _larger_decode(image_bytes, max_pixels, filename, parsed,
                                                                      decoded.gray))
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


def kept_orientation(insp: Inspection, mode: WriteMode = "file", naming: SidecarNaming = "ext",
                     filename: str | None = None) -> int | None:
    """The existing orientation a write would keep without ``force`` (what the target sidecar holds, else what viewers
    show now, when it is a valid value other than 1), else None: the same rule as :func:`plan_write`, known before any
    detection, since a kept value is kept whatever the photo shows."""
    target, _ = target_for(insp.format, mode, insp)
    if target == "xmp-sidecar":
        state = insp.sidecars.get(sidecar_name(filename or "photo", naming))
        if state is not None and state.value in VALID_ORIENTATIONS:
            return state.value if state.value != 1 else None
    shown = insp.shown()
    return shown if shown in VALID_ORIENTATIONS and shown != 1 else None


def _not_analysed(insp: Inspection, header, kept: int, detector: OrientationDetector, mode: WriteMode,
                  naming: SidecarNaming, filename: str | None, start: float) -> OrientationReport:
    """The report of a photo not analysed because its existing orientation ``kept`` is kept."""
    tag, detail = _valid_tag(insp.exif)
    shown = insp.shown()
    target, note = target_for(insp.format, mode, insp)
    why = f"the existing orientation {kept} is kept (force analyses the photo and replaces it)"
    plan = WritePlan(target="none", where=None, value=None, also=[], writer=None,
                     note="; ".join(n for n in (note, why) if n))
    return OrientationReport(
        decision="not_analysed", orientation=None, rotation_degrees=None, accepted_rotations=[], faces=[], cue="none",
        needs_review=False, confidence=None, reject_reason=None, text=TextReport(status="not_needed"),
        width=header.width, height=header.height, format=header.format, detector=detector.name,
        existing_orientation=shown if shown in VALID_ORIENTATIONS else tag,
        exif_status=insp.exif.status if insp.exif is not None else "not_applicable", exif_detail=detail,
        sources=insp.sources, conflicts=insp.conflicts(), write=plan, action="kept_existing", written=False,
        written_orientation=None, file_orientation=shown if header.format in ("heif", "avif") else tag,
        message=f"not analysed: {why}", elapsed_ms=_ms_since(start))


def _larger_decode(data: bytes, max_pixels: int, filename: str | None, header, gray):
    """The text cue's ``load``: the photo decoded ``factor`` times larger than ``gray`` (or as large as it is), for
    lines too small to see or read there; JPEGs at the smallest DCT scale that is large enough. The largest decode
    made is kept for the next request it serves."""
    made: list[np.ndarray] = []

    def load(factor: float):
        want = max(gray.shape) * factor
        if not made or max(made[0].shape) < min(want, max(header.width, header.height)):
            made[:] = [decode_at_least(data, want, max_pixels, filename=filename, header=header).gray]
        return made[0], made[0].shape[1] / gray.shape[1]
    return load


def _confidence(cue: Cue, rotation: int | None, faces: list[Face], text: TextReport) -> float | None:
    if rotation is None:
        return None
    if cue == "faces":
        scores = [f.score for f in faces if f.rotation == rotation and f.decisive and f.score is not None]
        return round(max(scores), 4) if scores else None
    agreeing = [r for r in text.readings if r.rotation_degrees == rotation]
    against = [r for r in text.readings if r.rotation_degrees == (rotation + 180) % 360]
    if not agreeing:
        return None
    real, other = agreeing[-1].real_words, against[-1].real_words if against else 0
    return round(real / (real + other), 2) if real + other else None


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
    readings = [TextReadingReport(reader=r.reader, rotation_degrees=r.turn, words=r.words, real_words=r.real,
                                  lines=r.lines, sample=list(r.sample))
                for v in result.readings for r in (v.first, v.second)]
    return TextReport(status="ran", rotation_degrees=result.rotation, reject_reason=result.reason, lines=result.lines,
                      zoomed=result.zoomed, readings=readings, script=result.script)


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
    tag and an orientation already shown produce no bytes; a photo whose existing orientation would be kept (other
    than 1, and ``force`` not set) is not analysed at all: its report says ``not_analysed``. ``inspection``: as for
    :func:`analyze`."""
    start = time.perf_counter()
    report, insp, action, value = _analyze(data, detector, max_pixels, filename, sidecars, mode, naming, force,
                                           inspection, skip_kept=True)
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
        "message": report.message if report.decision == "not_analysed" else f"{report.message}; {_ACTION_TEXT[action]}",
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
            what = f"text read upright: {text_result.summary()} (no decisive face)"
        else:
            what = "text read upright (no decisive face)"
        if rotation == 0:
            return f"upright as stored: {what}"
        return (f"rotated: turn {rotation} deg clockwise to show it upright "
                f"(EXIF {orientation_for_rotation(rotation)}); {what}")
    if text.status == "ran":
        faces_part = _describe(decision, faces, TextReport(status="not_needed"), None, "none", decision.reason)
        if text.rotation_degrees is not None:
            return (f"{faces_part}; the text points to {text.rotation_degrees} deg, which conflicts with the faces "
                    "(needs review)")
        why = {"no_cue": "no readable text", "conflicting_rotations": "the text's readings disagree",
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
