"""The four views, the exactly-one decision rule, and analyze / orient_file with a test-double detector."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from harness.photos import asymmetric_image
from tests.orientation.builders import FakeDetector, encode, insert_app1, jpeg, split_around_app1, tiff_block
from workers.orientation.detect import Face, decide
from workers.common.errors import InputError
from workers.common.images import EmptyImage
from workers.orientation.errors import TruncatedImage
from workers.orientation.exif import read_exif, write_orientation
from workers.orientation.geometry import ROTATIONS, TurnedViews, rotate_view, view_box_to_image
from workers.orientation.orient import analyze, orient_file


@pytest.mark.parametrize("rotation", ROTATIONS)
def test_a_box_found_in_a_view_maps_back_onto_the_same_pixels(rotation):
    image = np.zeros((60, 100), np.uint8)
    image[10:25, 70:90] = 255  # x 70..90, y 10..25
    view = rotate_view(image, rotation)
    ys, xs = np.nonzero(view)
    box = (xs.min(), ys.min(), xs.max() + 1 - xs.min(), ys.max() + 1 - ys.min())
    assert view_box_to_image(box, rotation, 100, 60) == pytest.approx((70, 10, 20, 15))


def test_views_are_clockwise_turns():
    image = np.arange(6, dtype=np.uint8).reshape(2, 3)  # [[0 1 2] [3 4 5]]
    assert rotate_view(image, 90).tolist() == [[3, 0], [4, 1], [5, 2]]
    assert rotate_view(image, 270).tolist() == [[2, 5], [1, 4], [0, 3]]
    assert rotate_view(image, 180).tolist() == [[5, 4, 3], [2, 1, 0]]


def test_turned_views_are_made_when_first_asked_for_and_kept():
    image = np.arange(6, dtype=np.uint8).reshape(2, 3)
    views = TurnedViews(image)
    assert len(views) == 0  # nothing turned yet
    assert views[90].tolist() == [[3, 0], [4, 1], [5, 2]]
    assert views[90] is views[90] and set(views) == {90}
    assert views[0] is image


def _face(rotation: int, decisive: bool = True) -> Face:
    return Face((0, 0, 10, 10), rotation, 0.9, (), "yunet", decisive)


def test_exactly_one_accepted_view_decides():
    d = decide([_face(90), _face(90)])
    assert (d.rotation, d.kind, d.accepted_rotations) == (90, "rotated", (90,))
    assert decide([_face(0)]).kind == "upright"


def test_no_accepted_view_rejects():
    d = decide([])
    assert (d.rotation, d.kind, d.accepted_rotations) == (None, "rejected", ())


@pytest.mark.parametrize("views", [(0, 180), (90, 270), (0, 90, 180), (0, 90, 180, 270)])
def test_several_accepted_views_reject(views):
    d = decide([_face(r) for r in views])
    assert (d.rotation, d.kind, d.accepted_rotations) == (None, "rejected", views)


def test_a_view_with_only_non_decisive_faces_rejects():
    assert decide([_face(90, decisive=False)]).kind == "rejected"
    assert decide([_face(90, decisive=False), _face(90)]).rotation == 90
    assert decide([_face(90, decisive=False), _face(0)]).kind == "rejected"  # a vote still conflicts


@pytest.mark.parametrize("rotation,value", [(0, 1), (90, 6), (180, 3), (270, 8)])
def test_analyze_reports_the_decision(rotation, value):
    report = analyze(jpeg(), FakeDetector((rotation,)))
    assert report.orientation == value and report.rotation_degrees == rotation
    assert report.decision == ("upright" if rotation == 0 else "rotated")
    assert report.accepted_rotations == [rotation] and len(report.faces) == 1
    assert report.detector == "fake" and report.elapsed_ms > 0 and report.action == "analysis_only"


@pytest.mark.parametrize("rotations", [(), (0, 180)])
def test_analyze_rejects_without_guessing(rotations):
    report = analyze(jpeg(), FakeDetector(rotations))
    assert report.decision == "rejected" and report.orientation is None and report.rotation_degrees is None
    assert report.accepted_rotations == list(rotations)
    assert "rejected" in report.message


def test_face_boxes_are_in_stored_pixels_and_the_detector_sees_stored_pixels():
    detector = FakeDetector((90,), box=(10, 20, 30, 40))
    data = write_orientation(jpeg(asymmetric_image(1600, 4000), 80), 8)  # an existing tag must not matter
    report = analyze(data, detector)
    assert detector.seen == [(200, 500)]  # decoded at 1/8 size, not turned by the tag
    assert report.faces[0].box == [80, 160, 240, 320]
    assert (report.width, report.height, report.format) == (4000, 1600, "jpeg")
    assert report.existing_orientation == 8 and report.exif_status == "ok"


def test_png_without_exif_is_analysed_and_would_get_an_exif_chunk():
    report = analyze(encode(asymmetric_image(), ".png"), FakeDetector((180,)))
    assert report.orientation == 3 and report.exif_status == "absent"
    assert report.write.target == "png-exif" and report.write.value == 3 and report.write.writer == "exiftool"


def _orient(data: bytes, detector: FakeDetector, force: bool = False):
    """(the photo's bytes after orient_file: its new bytes, else the input; the report)."""
    outcome = orient_file(data, detector, force)
    return (outcome.photo if outcome.photo is not None else data), outcome.report


@pytest.mark.parametrize("rotation,value", [(90, 6), (180, 3), (270, 8)])
def test_orient_file_writes_the_tag(rotation, value):
    before = jpeg()
    after, report = _orient(before, FakeDetector((rotation,)))
    assert report.written and report.written_orientation == value and report.action == "written"
    assert report.file_orientation == value
    assert read_exif(after).orientation == value
    assert split_around_app1(after)[1] == before[20:]  # everything after SOI + JFIF untouched


def test_orient_file_leaves_an_upright_photo_alone():
    before = jpeg()
    after, report = _orient(before, FakeDetector((0,)))
    assert after == before and not report.written and report.action == "already_set"
    assert report.file_orientation is None  # no EXIF at all: viewers show it as stored


def test_orient_file_never_tags_a_rejected_photo():
    before = write_orientation(jpeg(), 1)
    for rotations in [(), (90, 270)]:
        after, report = _orient(before, FakeDetector(rotations), force=True)
        assert after == before and report.action == "not_written_rejected" and report.written_orientation is None


def test_an_existing_tag_is_kept_unless_forced():
    before = write_orientation(jpeg(), 8)
    after, report = _orient(before, FakeDetector((90,)))
    assert after == before and report.action == "kept_existing" and report.existing_orientation == 8
    assert report.file_orientation == 8
    assert "force" in report.message
    after, report = _orient(before, FakeDetector((90,)), force=True)
    assert report.written and read_exif(after).orientation == 6


@pytest.mark.parametrize("existing", [1, 0])  # 0: an invalid value, as some writers leave
def test_tag_1_and_invalid_tags_are_replaced_without_force(existing):
    before = insert_app1(jpeg(), tiff_block([(274, 3, 1, struct.pack("<H", existing) + b"\0\0")]))
    assert read_exif(before).orientation == existing
    after, report = _orient(before, FakeDetector((270,)))
    assert report.written and read_exif(after).orientation == 8


def test_unreadable_exif_is_replaced_even_when_upright():
    before = write_orientation(jpeg(), 1)
    seg_start = before.index(b"Exif\x00\x00")
    broken = before[:seg_start + 10] + b"\xff\xff\xff\x7f" + before[seg_start + 14:]  # IFD0 offset far away
    assert read_exif(broken).status == "unreadable"
    after, report = _orient(broken, FakeDetector((0,)))
    assert report.exif_status == "unreadable" and report.exif_detail and report.written
    assert read_exif(after).orientation == 1


def test_a_damaged_heif_is_refused_before_detecting():
    detector = FakeDetector((90,))
    with pytest.raises(InputError):
        orient_file(b"\0\0\0\x18ftypheic" + b"\0" * 40, detector, filename="a.heic")
    assert detector.seen == []


def test_orient_file_bad_inputs():
    with pytest.raises(EmptyImage):
        _orient(b"", FakeDetector())
    data = jpeg(asymmetric_image(300, 400))
    with pytest.raises(TruncatedImage):
        _orient(data[:len(data) // 2], FakeDetector((90,)))
