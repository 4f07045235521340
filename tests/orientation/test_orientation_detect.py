"""The real detectors: configuration, the YuNet grouping and voting rule, and real faces when the data is there."""
from __future__ import annotations

import numpy as np
import pytest

from harness.photos import asymmetric_image
from tests.orientation.builders import jpeg
from workers.common.datasets import data_root, dataset
from workers.orientation.detect import (YUNET_MARGIN, YUNET_MIN_SCORE, DetectorConfig, Track, get_detector,
                                        group_tracks, yunet_votes)
from workers.orientation.faces import Candidate
from workers.orientation.geometry import ROTATIONS, rotate_view
from workers.orientation.parts import PART_CROP, PartSpec, PartVerifier
from workers.orientation.orient import analyze

YUNET = data_root().parent / "models" / "yunet" / "face_detection_yunet_2023mar.onnx"
FACES = dataset("faces", "dev")


def test_auto_config_is_paper_without_a_model_and_combined_with_one(tmp_path):
    assert DetectorConfig().resolved_method() == "paper"
    assert DetectorConfig(yunet_model=tmp_path / "m.onnx").resolved_method() == "combined"
    assert DetectorConfig(method="yunet", yunet_model=tmp_path / "m.onnx").resolved_method() == "yunet"


def test_detectors_are_built_once_per_configuration():
    assert get_detector(DetectorConfig()) is get_detector(DetectorConfig(method="paper"))
    assert get_detector(DetectorConfig()).name == "paper"


def test_yunet_methods_need_a_model(tmp_path):
    for method in ("yunet", "combined"):
        with pytest.raises(ValueError, match="YuNet model"):
            get_detector(DetectorConfig(method=method))
    with pytest.raises(FileNotFoundError, match="not found"):
        get_detector(DetectorConfig(yunet_model=tmp_path / "missing.onnx"))
    (tmp_path / "junk.onnx").write_bytes(b"not a network")
    with pytest.raises(FileNotFoundError, match="cannot load"):
        get_detector(DetectorConfig(yunet_model=tmp_path / "junk.onnx"))


def test_paper_detector_rejects_a_photo_without_faces():
    report = analyze(jpeg(asymmetric_image(300, 400)), get_detector(DetectorConfig()))
    assert report.decision == "rejected" and report.faces == [] and report.accepted_rotations == []


def test_parts_are_not_found_in_a_blank_face():
    verifier = PartVerifier(PartSpec.opencv())
    parts = verifier.parts(np.full((PART_CROP, PART_CROP), 128, np.uint8))
    assert parts == () and not verifier.accepts(parts)


def test_group_tracks_joins_one_face_seen_in_several_views():
    """A face at x 100..150, y 20..80 of a 400x300 image, seen upright (view 0) and upside down."""
    views = {0: [Candidate((100, 20, 50, 60), 0.93)],
             180: [Candidate((250, 220, 50, 60), 0.87), Candidate((10, 10, 30, 30), 0.6)]}
    tracks = group_tracks(views, 400, 300)
    assert len(tracks) == 2
    assert tracks[0].box == pytest.approx((100, 20, 50, 60)) and set(tracks[0].views) == {0, 180}
    rotation, score, margin = tracks[0].best()
    assert (rotation, score) == (0, 0.93) and margin == pytest.approx(0.06)


def _track(**scores: float) -> Track:
    track = Track((0, 0, 10, 10))
    for name, s in scores.items():
        track.views[int(name[1:])] = Candidate((0, 0, 10, 10), s)
    return track


def test_yunet_votes_need_a_score_and_decide_only_with_a_margin():
    clear = _track(r0=0.93, r180=0.5)
    close = _track(r0=0.93, r180=0.88)  # YuNet fires on upside-down faces too
    weak = _track(r90=YUNET_MIN_SCORE - 0.05)
    votes = yunet_votes([clear, close, weak], YUNET_MIN_SCORE, YUNET_MARGIN)
    assert votes == {(0, 0): ((), True), (1, 0): ((), False)}


REAL = ["openface/clapton-2.jpg", "face_recognition/examples_obama_small.jpg"]


def _configs() -> list[DetectorConfig]:
    configs = [DetectorConfig(method="paper")]
    if YUNET.is_file():
        configs.append(DetectorConfig(method="combined", yunet_model=YUNET))
    return configs


@pytest.mark.skipif(FACES is None, reason="needs $SWEEPCAST_DATA/faces/dev")
@pytest.mark.parametrize("name", REAL)
def test_real_faces_are_found_upright_in_every_rotation(name):
    import cv2

    upright = cv2.imread(str(FACES / name), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
    for config in _configs():
        detector = get_detector(config)
        for rotation in ROTATIONS:
            stored = jpeg(rotate_view(upright, (360 - rotation) % 360))
            report = analyze(stored, detector)
            assert report.rotation_degrees == rotation, (config.resolved_method(), rotation, report.message)


@pytest.mark.skipif(FACES is None, reason="needs $SWEEPCAST_DATA/faces/dev")
def test_parts_confirm_a_real_face_upright_and_not_upside_down():
    """The eye cascades run in turn until one gives a pair: the upright face still shows eyes and mouth in
    their places, and the same face upside down is not accepted."""
    import cv2

    from workers.orientation.detect import HAAR_MIN_NEIGHBORS, HAAR_SCALE_FACTOR, HAAR_SCAN
    from workers.orientation.faces import HaarFaceFinder
    from workers.orientation.parts import face_crop

    gray = cv2.imread(str(FACES / REAL[0]), cv2.IMREAD_GRAYSCALE)
    finder = HaarFaceFinder(HAAR_SCAN, HAAR_SCALE_FACTOR, HAAR_MIN_NEIGHBORS)
    (face,) = finder.find(gray)
    crop = face_crop(gray, face.box)
    verifier = PartVerifier(PartSpec.opencv())
    assert verifier.parts(crop) == ("eyes", "mouth")
    assert not verifier.accepts(verifier.parts(rotate_view(crop, 180)))


@pytest.mark.skipif(FACES is None, reason="needs $SWEEPCAST_DATA/faces/dev")
def test_the_search_around_a_face_finds_it_at_its_size_and_not_at_others():
    """Searched only where and at the sizes a region says, the Haar search finds the face the whole view's search
    finds (the box a search of the region at every size finds); a region whose sizes leave the face out finds nothing
    (the small windows, most of the CPU, are not searched for a large face)."""
    import cv2

    from workers.orientation.detect import HAAR_MIN_NEIGHBORS, HAAR_SCALE_FACTOR, HAAR_SCAN, Track, search_regions
    from workers.orientation.faces import HaarFaceFinder, Region
    from workers.orientation.geometry import iou

    gray = cv2.imread(str(FACES / REAL[0]), cv2.IMREAD_GRAYSCALE)
    finder = HaarFaceFinder(HAAR_SCAN, HAAR_SCALE_FACTOR, HAAR_MIN_NEIGHBORS)
    (face,) = finder.find(gray)
    x, y, w, h = face.box
    (around,) = search_regions([Track((x + 0.1 * w, y + 0.15 * h, 0.8 * w, 0.8 * h))], gray.shape)  # YuNet's box
    assert around.sides[0] < w < around.sides[1]
    (found,) = finder.find(gray, [around])
    assert found == finder.find(gray, [Region(around.box, (1.0, float(max(gray.shape))))])[0]
    assert iou(found.box, face.box) > 0.8
    assert finder.find(gray, [Region(around.box, (w / 4, w / 2))]) == []
    assert finder.find(gray, [Region(around.box, (2 * w, 4 * w))]) == []


@pytest.mark.skipif(FACES is None, reason="needs $SWEEPCAST_DATA/faces/dev")
def test_dog_photo_is_never_given_a_wrong_rotation():
    import cv2

    upright = cv2.imread(str(FACES / "dlib_examples_faces" / "dogs.jpg"), cv2.IMREAD_COLOR)
    for config in _configs():
        for rotation in (0, 90):
            report = analyze(jpeg(rotate_view(upright, (360 - rotation) % 360)), get_detector(config))
            assert report.rotation_degrees in (None, rotation)


@pytest.mark.skipif(FACES is None or not YUNET.is_file(), reason="needs $SWEEPCAST_DATA/faces/dev and the YuNet model")
def test_small_faces_of_a_group_photo_are_found_by_the_second_yunet_scan():
    import cv2

    from workers.orientation.detect import YuNetDetector

    face = cv2.imread(str(FACES / REAL[0]), cv2.IMREAD_GRAYSCALE)
    small = cv2.resize(face, None, fx=100 / max(face.shape), fy=100 / max(face.shape), interpolation=cv2.INTER_AREA)
    group = np.full((900, 900), 128, np.uint8)  # faces ~1/9 of the long side: ~7 px at a 320 px scan
    for y in (100, 400, 700):
        for x in (100, 400, 700):
            group[y:y + small.shape[0], x:x + small.shape[1]] = small
    turned = rotate_view(group, 270)  # the upright group after a 90 degree clockwise turn
    coarse_only = YuNetDetector(YUNET, PartSpec.opencv(), scan_sizes=(320,))
    assert coarse_only.upright_faces(turned) == []
    report = analyze(jpeg(turned), get_detector(DetectorConfig(method="combined", yunet_model=YUNET)))
    assert report.rotation_degrees == 90, report.message


@pytest.mark.skipif(FACES is None, reason="needs $SWEEPCAST_DATA/faces/dev")
def test_the_second_haar_search_decides_a_photo_in_which_the_first_found_no_face():
    import cv2

    from workers.orientation.detect import HAAR_MIN_NEIGHBORS, HAAR_SCALE_FACTOR, HAAR_SCAN, PaperDetector
    from workers.orientation.faces import LongSideScan

    turned = rotate_view(cv2.imread(str(FACES / REAL[0]), cv2.IMREAD_GRAYSCALE), 270)
    blind = {"scan": LongSideScan(40, 30), "scale_factor": 1.25, "min_neighbors": 2}  # too coarse to see a face
    assert PaperDetector(PartSpec.opencv(), **blind, second=None).upright_faces(turned) == []
    both = PaperDetector(PartSpec.opencv(), **blind, second=(HAAR_SCAN, HAAR_SCALE_FACTOR, HAAR_MIN_NEIGHBORS))
    assert {f.rotation for f in both.upright_faces(turned)} == {90}


HOPPER = dataset("exif", "pillow_hopper")


@pytest.mark.skipif(HOPPER is None, reason="needs $SWEEPCAST_DATA/exif/pillow_hopper")
@pytest.mark.parametrize("value", [3, 6, 8])
def test_detected_orientation_matches_the_real_tag_of_a_turned_portrait(value):
    """Pillow's hopper_orientation_N.jpg store the portrait turned and carry the correct tag N."""
    data = (HOPPER / f"hopper_orientation_{value}.jpg").read_bytes()
    for config in _configs():
        report = analyze(data, get_detector(config))
        assert report.existing_orientation == value and report.orientation == value


def test_the_haar_scan_follows_the_photos_short_side():
    """The smallest face searched is a share of the short side, scanned at a fixed size: a 3:2 view, a 4:3 one and a
    panorama all get a 364 px short side; faces from 26 px up to the whole short side. A small view is not enlarged."""
    from workers.orientation.detect import HAAR_SCAN
    from workers.orientation.faces import LongSideScan

    assert HAAR_SCAN.plan(600, 900) == (pytest.approx(364 / 600), 26, 364)
    assert HAAR_SCAN.plan(900, 675) == (pytest.approx(364 / 675), 26, 364)
    assert HAAR_SCAN.plan(300, 900) == (1.0, 26, 300)  # a panorama's faces keep their size
    assert HAAR_SCAN.plan(240, 320) == (1.0, 26, 240)
    # the previous release shrank the long side to 360 px: the panorama's faces to 0.4x
    assert LongSideScan(360, 22).plan(300, 900) == (pytest.approx(0.4), 22, 0)


# ---- never a decision on nothing: a Haar face YuNet did not see (issue 54) --------------------------------------------

class _SeesNothing:
    """A YuNet finder that finds no face anywhere (what YuNet does on aerial photos and textures)."""

    def find_turned(self, gray, scan_size, rotations):
        return {r: [] for r in rotations}


class _SpyPaper:
    """The paper's detector, recording the searches asked of it and answering a face accepted at view 90."""

    name = "paper"

    def __init__(self, faces):
        self.faces, self.calls = faces, []

    def upright_faces(self, gray, regions=None):
        self.calls.append(regions)
        return list(self.faces)


def _combined_with(finder, paper):
    from workers.orientation.detect import YuNetDetector

    detector = YuNetDetector.__new__(YuNetDetector)
    detector.name, detector.min_score, detector.margin, detector.scan_sizes = "combined", 0.8, 0.1, (320, 640)
    detector.paper, detector._verifier = paper, None
    detector._finder = type("PerThread", (), {"get": staticmethod(lambda: finder)})()
    return detector


def test_the_papers_search_does_not_run_where_yunet_sees_no_face():
    from workers.orientation.detect import Face

    haar = Face((40, 40, 60, 60), 90, None, ("eyes", "mouth"), "haar")
    paper = _SpyPaper([haar])
    faces = _combined_with(_SeesNothing(), paper).upright_faces(np.zeros((300, 400), np.uint8))
    assert faces == [] and paper.calls == []  # not even searched: a Haar face alone could not decide


def test_a_haar_face_yunet_did_not_see_votes_but_cannot_decide():
    from workers.orientation.detect import Face, decide, haar_only_not_decisive, search_regions

    seen = [Track((100, 100, 50, 60))]
    on_it = Face((95, 90, 60, 70), 0, None, ("eyes",), "haar")
    elsewhere = Face((300, 20, 40, 40), 90, None, ("eyes", "mouth"), "haar")
    kept = haar_only_not_decisive([on_it, elsewhere], seen)
    assert kept[0].decisive and not kept[1].decisive
    assert decide(kept[1:]).rotation is None and decide(kept[1:]).reason == "low_confidence"
    (region,) = search_regions(seen, (300, 400))
    x, y, w, h = region.box
    assert x < 100 and y < 100 and x + w > 150 and y + h > 160 and x >= 0 and y >= 0  # around YuNet's face, grown


def _noup_images():
    folder = dataset("orientation", "noup")
    aerial = dataset("sfm", "drone_fc350", "images")
    found = sorted(folder.iterdir()) if folder else []
    found += sorted(aerial.iterdir())[:3] if aerial else []
    return [p for p in found if p.suffix.lower() in (".jpg", ".jpeg", ".png")]


@pytest.mark.data
@pytest.mark.skipif(not YUNET.is_file() or not _noup_images(), reason="needs the YuNet model and $SWEEPCAST_DATA's "
                                                                     "aerial and texture images")
def test_aerial_photos_and_textures_are_never_decided_by_a_face():
    import cv2

    engine = get_detector(DetectorConfig(method="combined", yunet_model=YUNET, text=False))
    for path in _noup_images():
        image = cv2.imread(str(path), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
        image = cv2.resize(image, None, fx=min(1.0, 1200 / max(image.shape)), fy=min(1.0, 1200 / max(image.shape)),
                           interpolation=cv2.INTER_AREA)
        for rotation in ROTATIONS:
            report = analyze(jpeg(rotate_view(image, rotation)), engine)
            assert report.rotation_degrees is None and report.cue == "none", (path.name, rotation, report.faces)


def test_a_job_checks_its_configuration_without_building_the_text_cue(monkeypatch, tmp_path):
    from workers.orientation import detect

    def no_text(*args):
        raise AssertionError("the text cue was built to check a configuration")

    monkeypatch.setattr(detect, "get_text_cue", no_text)
    assert detect.face_detector(DetectorConfig(method="paper", text=True)).name == "paper"
    with pytest.raises(ValueError, match="needs a YuNet model"):
        detect.face_detector(DetectorConfig(method="combined", text=True))
    with pytest.raises(FileNotFoundError):
        detect.face_detector(DetectorConfig(yunet_model=tmp_path / "missing.onnx", text=True))
