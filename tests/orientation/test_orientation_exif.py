"""The EXIF Orientation tag: the rotation mapping rendered by a real decoder, and lossless writing."""
from __future__ import annotations

import struct

import cv2
import numpy as np
import piexif
import pytest

from harness.photos import asymmetric_image
from tests.orientation.builders import encode, ifd0_entries, insert_app1, jpeg, rich_exif, split_around_app1, tiff_block
from workers.common.datasets import dataset
from workers.common.images import UnsupportedImage
from workers.orientation.exif import orientation_for_rotation, read_exif, write_orientation
from workers.orientation.geometry import ROTATIONS, rotate_view
from workers.orientation.headers import parse_header


def test_rotation_to_orientation_values():
    assert [orientation_for_rotation(r) for r in (0, 90, 180, 270)] == [1, 6, 3, 8]
    with pytest.raises(ValueError):
        orientation_for_rotation(45)


@pytest.mark.parametrize("rotation", ROTATIONS)
@pytest.mark.parametrize("ext", [".jpg", ".webp"])
def test_written_tag_makes_a_decoder_show_the_photo_upright(rotation, ext):
    """Store the upright picture turned the other way, tag it, and let OpenCV (which applies the
    tag) render it: the result must be the upright picture."""
    upright = asymmetric_image(120, 200)
    stored = rotate_view(upright, (360 - rotation) % 360)
    params = [cv2.IMWRITE_JPEG_QUALITY, 95] if ext == ".jpg" else [cv2.IMWRITE_WEBP_QUALITY, 95]
    tagged = write_orientation(encode(stored, ext, params), orientation_for_rotation(rotation))
    shown = cv2.imdecode(np.frombuffer(tagged, np.uint8), cv2.IMREAD_COLOR)
    assert shown.shape == upright.shape
    assert np.abs(shown.astype(int) - upright).mean() < 4
    for other in ROTATIONS:  # and no other rotation's tag would have done so
        if other != rotation and rotate_view(stored, other).shape == upright.shape:
            assert np.abs(rotate_view(stored, other).astype(int) - upright).mean() > 20


def _assert_only_orientation_changed(before: bytes, after: bytes, value: int) -> None:
    head_b, tail_b = split_around_app1(before)
    head_a, tail_a = split_around_app1(after)
    assert head_a == head_b, "segments before the EXIF block changed"
    assert tail_a == tail_b, "segments after the EXIF block or the compressed data changed"
    old, new = piexif.load(before), piexif.load(after)
    assert new["0th"][274] == value
    for ifd in ("0th", "Exif", "GPS", "Interop", "1st"):
        old_tags = {k: v for k, v in old[ifd].items() if not (ifd == "0th" and k == 274)}
        new_tags = {k: v for k, v in new[ifd].items() if not (ifd == "0th" and k == 274)}
        assert new_tags == old_tags, ifd
    assert new["thumbnail"] == old["thumbnail"] and old["thumbnail"]


def test_existing_tag_is_patched_in_place():
    before = insert_app1(jpeg(), rich_exif(orientation=1))
    after = write_orientation(before, 6)
    assert len(after) == len(before)
    _assert_only_orientation_changed(before, after, 6)
    entries_b, entries_a = ifd0_entries(before), ifd0_entries(after)
    assert {t: e for t, e in entries_a.items() if t != 274} == {t: e for t, e in entries_b.items() if t != 274}


def test_missing_tag_is_added_without_moving_anything_else():
    before = insert_app1(jpeg(), rich_exif(orientation=None))
    after = write_orientation(before, 8)
    _assert_only_orientation_changed(before, after, 8)
    assert read_exif(after).orientation == 8
    entries_b, entries_a = ifd0_entries(before), ifd0_entries(after)
    assert 274 not in entries_b and set(entries_a) == set(entries_b) | {274}
    assert all(entries_a[t] == e for t, e in entries_b.items())  # byte-identical, offsets still valid
    assert list(entries_a) == sorted(entries_a)


@pytest.mark.parametrize("endian", ["<", ">"])
def test_unknown_private_tags_survive(endian):
    """piexif would drop tags it does not know when re-serialising; the byte-level edit keeps them."""
    make = (271, 2, 4, b"Cam\0")
    private = (0xC7A1, 4, 1, struct.pack(endian + "I", 7))
    before = insert_app1(jpeg(), tiff_block([make, private], endian))
    for value in (3, 6):
        after = write_orientation(before, value)
        entries = ifd0_entries(after)
        assert entries[0xC7A1][-4:] == struct.pack(endian + "I", 7)
        assert read_exif(after).orientation == value
        before = after  # second round patches the tag added by the first


def test_jpeg_without_exif_gets_a_block_after_its_jfif_header():
    before = jpeg()
    after = write_orientation(before, 3)
    assert read_exif(before).status == "absent" and read_exif(after).orientation == 3
    segs = parse_header(after).segments
    assert [s.marker for s in segs[:2]] == [0xE0, 0xE1]  # JFIF first, as JFIF requires
    seg = segs[1]
    assert after[:seg.start] + after[seg.end:] == before


def test_unreadable_exif_is_reported_and_replaced():
    """An IFD0 offset pointing outside the block: unreadable, replaced by a valid block with the tag."""
    broken = b"Exif\x00\x00II*\x00" + struct.pack("<I", 5000) + b"\0" * 16
    before = insert_app1(jpeg(), broken)
    info = read_exif(before)
    assert info.status == "unreadable" and info.detail
    after = write_orientation(before, 6)
    assert read_exif(after).status == "ok" and read_exif(after).orientation == 6
    assert split_around_app1(after) == split_around_app1(before)


def test_webp_tag_keeps_the_image_chunk():
    data = encode(asymmetric_image(), ".webp", [cv2.IMWRITE_WEBP_QUALITY, 80])
    tagged = write_orientation(data, 6)
    assert read_exif(tagged).orientation == 6
    assert data[12:] .startswith(b"VP8 ") and data[12:] in tagged
    assert read_exif(write_orientation(tagged, 3)).orientation == 3


def test_png_cannot_be_tagged():
    with pytest.raises(UnsupportedImage, match="PNG"):
        write_orientation(encode(asymmetric_image(), ".png"), 6)
    with pytest.raises(UnsupportedImage):
        read_exif(encode(asymmetric_image(), ".png"))


def test_invalid_value_is_refused():
    with pytest.raises(ValueError):
        write_orientation(jpeg(), 9)


# --- real files (skipped without the benchmark data) ---------------------------------------------

EXIF_DATA = dataset("exif")


@pytest.mark.skipif(EXIF_DATA is None, reason="needs $SWEEPCAST_DATA/exif")
def test_real_corrupt_exif_from_pillow_is_replaced():
    path = EXIF_DATA / "pillow_hopper" / "hopper_bad_exif.jpg"
    before = path.read_bytes()
    assert read_exif(before).status == "unreadable"
    after = write_orientation(before, 8)
    assert read_exif(after).orientation == 8
    assert split_around_app1(after) == split_around_app1(before)
    assert cv2.imdecode(np.frombuffer(after, np.uint8), cv2.IMREAD_COLOR) is not None


@pytest.mark.skipif(EXIF_DATA is None, reason="needs $SWEEPCAST_DATA/exif")
@pytest.mark.parametrize("value", range(0, 9))
def test_real_camera_style_files_keep_every_other_tag(value):
    before = (EXIF_DATA / f"Landscape_{value}.jpg").read_bytes()
    assert read_exif(before).orientation == value
    after = write_orientation(before, 6)
    _assert_stream_and_tags_kept(before, after)


def _assert_stream_and_tags_kept(before: bytes, after: bytes) -> None:
    assert split_around_app1(after) == split_around_app1(before)
    old, new = piexif.load(before), piexif.load(after)
    assert new["0th"][274] == 6
    assert {k: v for k, v in new["0th"].items() if k != 274} == {k: v for k, v in old["0th"].items() if k != 274}
    assert all(new[ifd] == old[ifd] for ifd in ("Exif", "GPS", "Interop", "1st"))


@pytest.mark.skipif(EXIF_DATA is None, reason="needs $SWEEPCAST_DATA/exif")
def test_real_tags_2_to_8_are_read():
    for value in range(2, 9):
        path = EXIF_DATA / "pillow_hopper" / f"hopper_orientation_{value}.jpg"
        assert read_exif(path.read_bytes()).orientation == value
