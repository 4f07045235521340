"""Every format a photo library holds: reading each orientation source, writing where the format keeps
the tag (bytes outside it kept), sidecars, conflicts, and the library walk's idempotence.

Generated edge cases run everywhere; the real files of ``$SWEEPCAST_DATA/orientation/formats`` and
``$SWEEPCAST_DATA/exif`` are used when present. Writes through exiftool are skipped without it."""
from __future__ import annotations

import argparse
import hashlib
import io
import json
import shutil
import struct
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from harness.photos import asymmetric_image, gray_pages, tiff
from tests.orientation.builders import FakeDetector, avif, encode, exiftool_runs, insert_xmp, jpeg, xmp_packet
from workers.common.datasets import dataset
from workers.orientation import cli
from workers.orientation.bmff import read_heif
from workers.orientation.exif import read_exif
from workers.orientation.geometry import apply_orientation, heif_orientation, turn_orientation
from workers.orientation.headers import parse_header
from workers.orientation.metadata import inspect, new_sidecar, png_chunks, write_png_orientation, write_tiff_orientation
from workers.orientation.orient import analyze, orient_file
from workers.orientation.xmp import existing_sidecars, patch_packet, read_packet, sidecar_bytes, sidecar_path

HAS_EXIFTOOL = exiftool_runs()
needs_exiftool = pytest.mark.skipif(not HAS_EXIFTOOL, reason="exiftool (libimage-exiftool-perl) is not installed")
FORMATS = dataset("orientation", "formats")
needs_formats = pytest.mark.skipif(FORMATS is None, reason="needs $SWEEPCAST_DATA/orientation/formats")


def differing(a: bytes, b: bytes) -> list[int]:
    assert len(a) == len(b)
    return [i for i in range(len(a)) if a[i] != b[i]]


# --- the orientation algebra -----------------------------------------------------------------------

def test_heif_transforms_and_turns_have_known_exif_values():
    assert heif_orientation([]) == 1
    assert heif_orientation([("irot", 3)]) == 6  # 270 deg counter-clockwise = 90 clockwise (iPhone: EXIF 6)
    assert heif_orientation([("irot", 1)]) == 8 and heif_orientation([("irot", 2)]) == 3
    assert heif_orientation([("irot", 1), ("imir", 0)]) == 5  # Pillow maps rot1mir0.avif to 5
    assert heif_orientation([("imir", 1)]) == 2 and heif_orientation([("imir", 0)]) == 4
    assert [turn_orientation(1, r) for r in (0, 90, 180, 270)] == [1, 6, 3, 8]
    assert turn_orientation(6, 0) == 6 and turn_orientation(6, 90) == 3 and turn_orientation(6, 270) == 1
    assert turn_orientation(2, 90) == 7  # a mirrored display turned 90 clockwise: transverse


@pytest.mark.parametrize("value", range(1, 9))
def test_generated_avif_irot_imir_read_back_as_the_encoded_orientation(value):
    """Pillow's AVIF encoder turns an EXIF orientation into irot/imir; reading them back gives the same value,
    and the displayed image the detector sees is the upright picture."""
    upright = asymmetric_image(60, 100)
    inverse = {1: 1, 2: 2, 3: 3, 4: 4, 5: 5, 6: 8, 7: 7, 8: 6}[value]
    stored = np.ascontiguousarray(apply_orientation(upright, inverse))
    data = avif(stored, value)
    assert heif_orientation(read_heif(data).transforms) == value
    from workers.orientation.decode import decode_gray

    shown = decode_gray(data).gray
    expected = cv2.cvtColor(upright, cv2.COLOR_BGR2GRAY)
    assert shown.shape == expected.shape
    assert np.abs(shown.astype(int) - expected).mean() < 8


# --- TIFF ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("endian", ["<", ">"])
@pytest.mark.parametrize("existing", [None, 1, 3])
def test_tiff_tag_is_written_in_ifd0_keeping_every_page(endian, existing):
    pages = gray_pages(3)
    before = tiff(pages, endian, existing)
    after = write_tiff_orientation(before, 6)
    im = Image.open(io.BytesIO(after))
    assert im.getexif()[274] == 6 and im.n_frames == 3
    for i, page in enumerate(pages):  # Pillow applies IFD0's tag to the first page when it decodes it
        im.seek(i)
        assert np.array_equal(np.asarray(im), np.ascontiguousarray(apply_orientation(page, 6)) if i == 0 else page)
    if existing is not None:  # one SHORT: its value bytes patched in place, nothing else
        assert len(after) == len(before) and len(differing(before, after)) == 1
    else:  # a copy of IFD0 appended; only the header's 4-byte pointer changes in the original bytes
        assert after[8:len(before)] == before[8:] and after[:4] == before[:4]
    assert inspect(after, parse_header(after)).shown() == 6


def test_tiff_orientation_stored_as_long_is_rewritten_as_short():
    before = tiff(gray_pages(1), "<", 3, orientation_type=4)
    after = write_tiff_orientation(before, 8)
    assert Image.open(io.BytesIO(after)).getexif()[274] == 8


@pytest.mark.parametrize("rotation", [90, 180, 270])
def test_tiff_is_decoded_as_stored_whatever_its_tag(rotation):
    page = gray_pages(1, 40, 64)[0]
    for tag in (None, 1, 6, 8):
        decoded = analyze(tiff([page], ">", tag), FakeDetector((rotation,)))
        assert decoded.format == "tiff" and (decoded.width, decoded.height) == (64, 40)
    from workers.orientation.decode import decode_gray

    assert np.array_equal(decode_gray(tiff([page], "<", 6)).gray, page)


def test_tiff_with_embedded_xmp_gets_both_values_agreeing():
    """A TIFF whose XMP (tag 700) says 3 and whose IFD0 says 1: the conflict is reported, and writing 6
    sets both, in place (the packet keeps its length)."""
    packet = xmp_packet(3)
    base = tiff(gray_pages(1), "<", 1)
    # append the packet and an IFD0 entry for it by rebuilding IFD0 at the end (as our writer does)
    endian, ifd = "<", struct.unpack_from("<I", base, 4)[0]
    count = struct.unpack_from("<H", base, ifd)[0]
    entries = [base[ifd + 2 + 12 * i:ifd + 14 + 12 * i] for i in range(count)]
    xmp_at = len(base)
    body = base + packet + (b"\0" if len(packet) & 1 else b"")
    entries.append(struct.pack(endian + "HHII", 700, 1, len(packet), xmp_at))
    entries.sort(key=lambda e: struct.unpack_from("<H", e)[0])
    new_ifd = len(body)
    data = body + struct.pack("<H", len(entries)) + b"".join(entries) + b"\0\0\0\0"
    data = data[:4] + struct.pack("<I", new_ifd) + data[8:]
    insp = inspect(data, parse_header(data))
    assert [(s.kind, s.value) for s in insp.sources] == [("exif-ifd0", 1), ("xmp-embedded", 3)]
    assert insp.conflicts() and insp.shown() == 1
    outcome = orient_file(data, FakeDetector((90,)), filename="scan.tif")
    assert outcome.report.write.target == "exif-ifd0" and outcome.report.write.also == ["XMP packet in the file"]
    out = outcome.photo
    assert len(out) == len(data) and len(differing(data, out)) == 2  # one value byte each
    after = inspect(out, parse_header(out))
    assert {s.value for s in after.sources} == {6} and not after.conflicts()


# --- PNG -------------------------------------------------------------------------------------------

def _chunk_types(data: bytes) -> list[bytes]:
    return [kind for kind, *_ in png_chunks(data)]


@needs_exiftool
def test_png_without_exif_gets_an_exif_chunk_before_idat():
    before = encode(asymmetric_image(), ".png")
    after = write_png_orientation(before, 6)
    types = _chunk_types(after)
    assert b"eXIf" in types and types.index(b"eXIf") < types.index(b"IDAT")
    assert inspect(after, parse_header(after)).shown() == 6
    assert Image.open(io.BytesIO(after)).getexif()[274] == 6
    assert _chunks_except_exif(after) == _chunks_except_exif(before)  # every other chunk byte-identical


def _chunks_except_exif(data: bytes) -> list[bytes]:
    return [data[start:end + 4] for kind, start, _, end in png_chunks(data) if kind != b"eXIf"]


@needs_exiftool
def test_png_exif_after_idat_is_moved_before_it_and_updated():
    plain = encode(asymmetric_image(), ".png")
    exif_body = Image.Exif()
    exif_body[274] = 3
    tiff_bytes = exif_body.tobytes()[6:] if exif_body.tobytes().startswith(b"Exif") else exif_body.tobytes()
    import zlib

    chunk = struct.pack(">I", len(tiff_bytes)) + b"eXIf" + tiff_bytes + struct.pack(">I", zlib.crc32(b"eXIf" + tiff_bytes))
    iend = plain.rindex(b"IEND") - 4
    before = plain[:iend] + chunk + plain[iend:]
    assert inspect(before, parse_header(before)).shown() == 3
    after = write_png_orientation(before, 8)
    types = _chunk_types(after)
    assert types.count(b"eXIf") == 1 and types.index(b"eXIf") < types.index(b"IDAT")
    assert inspect(after, parse_header(after)).shown() == 8
    assert _chunks_except_exif(after) == _chunks_except_exif(before)


# --- XMP -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("form", ["attribute", "element"])
def test_xmp_value_is_read_and_patched_in_place(form):
    packet = xmp_packet(1, form)
    assert read_packet(packet).value == 1
    patched = patch_packet(packet, 8)
    assert len(patched) == len(packet) and len(differing(packet, patched)) == 1
    assert read_packet(patched).value == 8


def test_xmp_without_a_value_or_with_bad_xml():
    assert read_packet(xmp_packet(None)).status == "absent" and patch_packet(xmp_packet(None), 6) is None
    assert read_packet(b"<x:xmpmeta xmlns:x='adobe:ns:meta/'><rdf:RDF").status == "unreadable"
    bomb = (b'<?xml version="1.0"?><!DOCTYPE x [<!ENTITY a "aaaa"><!ENTITY b "&a;&a;&a;">]>'
            b'<x:xmpmeta xmlns:x="adobe:ns:meta/">&b;</x:xmpmeta>')
    assert read_packet(bomb).status == "unreadable"  # defusedxml: no entity expansion
    two_digit = xmp_packet(0, pad=0).replace(b'Orientation="0"', b'Orientation="10"')
    assert read_packet(two_digit).value == 10  # invalid, reported as it is
    patched = patch_packet(two_digit, 6)  # one digit fewer: the padding before the trailer takes the byte
    assert len(patched) == len(two_digit) and read_packet(patched).value == 6
    assert patch_packet(xmp_packet(3, pad=0).replace(b'<?xpacket end="w"?>', b""), 6) is not None
    assert patch_packet(two_digit.replace(b'<?xpacket end="w"?>', b""), 6) is None  # nowhere to keep the length


def test_new_sidecar_is_minimal_and_readable():
    data = new_sidecar(6)
    assert read_packet(data).value == 6 and data.startswith(b"<?xpacket begin=")


@needs_exiftool
def test_exiftool_reads_our_sidecar_and_adds_the_value_to_a_sidecar_without_one(tmp_path):
    from workers.orientation import exiftool

    path = tmp_path / "a.xmp"
    path.write_bytes(new_sidecar(8))
    assert exiftool.run(["-n", "-s3", "-XMP-tiff:Orientation", str(path)]).stdout.strip() == b"8"
    added = sidecar_bytes(3, xmp_packet(None))
    assert read_packet(added).value == 3 and b"image/jpeg" in added  # other properties kept


def test_sidecar_names(tmp_path):
    photo = tmp_path / "IMG_1.HEIC"
    assert sidecar_path(photo).name == "IMG_1.HEIC.xmp" and sidecar_path(photo, "stem").name == "IMG_1.xmp"
    (tmp_path / "IMG_1.xmp").write_bytes(new_sidecar(1))
    (tmp_path / "IMG_1.HEIC.xmp").write_bytes(new_sidecar(6))
    assert [p.name for p in existing_sidecars(photo)] == ["IMG_1.HEIC.xmp", "IMG_1.xmp"]


def test_jpeg_embedded_xmp_conflict_is_reported_and_fixed_by_a_write():
    data = insert_xmp(jpeg(), xmp_packet(3))
    report = analyze(data, FakeDetector((90,)))
    assert [(s.kind, s.value) for s in report.sources] == [("xmp-embedded", 3)]
    assert report.existing_orientation == 3
    sidecars = {"p.jpg.xmp": new_sidecar(8)}
    outcome = orient_file(data, FakeDetector((90,)), force=True, filename="p.jpg", sidecars=sidecars)
    assert outcome.report.conflicts  # XMP 3 vs sidecar 8
    assert outcome.report.write.also == ["XMP packet in the file", "p.jpg.xmp"]
    out = outcome.photo
    assert read_exif(out).orientation == 6
    after = inspect(out, parse_header(out), {"p.jpg.xmp": outcome.updated_sidecars["p.jpg.xmp"]})
    assert {s.value for s in after.sources} == {6} and not after.conflicts()


def test_sidecar_mode_never_changes_the_photo():
    data = jpeg()
    outcome = orient_file(data, FakeDetector((270,)), filename="scan.jpg", mode="sidecar")
    assert outcome.photo is None and outcome.sidecar_name == "scan.jpg.xmp"
    assert read_packet(outcome.sidecar).value == 8 and outcome.report.write.target == "xmp-sidecar"
    outcome = orient_file(data, FakeDetector((270,)), filename="scan.jpg", mode="sidecar", naming="stem")
    assert outcome.sidecar_name == "scan.xmp"


# --- HEIF / AVIF / RAW: never written ------------------------------------------------------------

def test_avif_gets_a_sidecar_with_the_turn_combined_with_its_irot():
    data = avif(asymmetric_image(60, 100), 6)
    report = analyze(data, FakeDetector((0,)), filename="a.avif")
    assert report.existing_orientation == 6 and report.orientation == 6 and report.write.target == "none"
    outcome = orient_file(data, FakeDetector((90,)), force=True, filename="a.avif")
    assert outcome.photo is None and outcome.report.write.target == "xmp-sidecar"
    assert read_packet(outcome.sidecar).value == turn_orientation(6, 90) == 3
    kept = orient_file(data, FakeDetector((90,)), filename="a.avif")
    assert kept.report.action == "kept_existing" and kept.sidecar is None


def test_raw_named_tiff_is_never_written():
    data = tiff(gray_pages(1), "<", None)
    insp = inspect(data, parse_header(data, "IMG_1.NEF"))
    assert insp.format == "raw"
    from workers.orientation.metadata import target_for

    assert target_for("raw", "file", insp)[0] == "xmp-sidecar"


# --- the library walk: a second run changes nothing ---------------------------------------------

def run_cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="sweepcast")
    cli.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args([*argv, "--jobs", "1"])  # in this process: the tests' fake detectors stay in it
    return args.func(args)


def library_hash(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def make_library(root: Path) -> None:
    (root / "scans").mkdir(parents=True)
    (root / "scans" / "a.jpg").write_bytes(jpeg())
    (root / "scans" / "b.tif").write_bytes(tiff(gray_pages(2), ">", None))
    (root / "c.avif").write_bytes(avif(asymmetric_image(60, 100)))
    (root / "d.jpg").write_bytes(insert_xmp(jpeg(), xmp_packet(1)))
    (root / "notes.txt").write_text("not a photo")
    if HAS_EXIFTOOL:
        (root / "e.png").write_bytes(encode(asymmetric_image(), ".png"))


@pytest.mark.parametrize("mode", ["--write", "--sidecar"])
def test_second_run_over_a_library_changes_nothing(tmp_path, monkeypatch, mode, capsys):
    detector = FakeDetector((90,))
    monkeypatch.setattr(cli, "get_detector", lambda config: detector)
    lib, reports = tmp_path / "library", tmp_path / "reports"
    make_library(lib)
    original = library_hash(lib)
    assert run_cli(["orient", str(lib), mode, "--report", str(reports / "first")]) == 0
    first = library_hash(lib)
    first_rows = json.loads((reports / "first.json").read_text())
    photos = 5 if HAS_EXIFTOOL else 4
    assert len(first_rows) == photos and all(r["action"].startswith("written 6") for r in first_rows)
    if mode == "--sidecar":
        assert all(first[k] == v for k, v in original.items())  # no photo changed
        assert sorted(set(first) - set(original)) == sorted(
            f"{name}.xmp" for name in original if name != "notes.txt")
    else:
        assert set(first) - set(original) == {"c.avif.xmp"}  # AVIF: a sidecar; the others in place
        assert read_exif((lib / "scans" / "a.jpg").read_bytes()).orientation == 6
        assert read_packet(_xmp_of(lib / "d.jpg")).value == 6  # the embedded XMP agrees
    detector.seen.clear()
    assert run_cli(["orient", str(lib), mode, "--report", str(reports / "second")]) == 0
    assert library_hash(lib) == first  # nothing new
    assert detector.seen == []  # every photo skipped as already tagged, none analysed again
    rows = json.loads((reports / "second.json").read_text())
    assert all(r["action"] == "skipped: already tagged (6)" and r["written_to"] == [] for r in rows)
    csv_text = (reports / "second.csv").read_text()
    assert csv_text.splitlines()[0].startswith("path,format,decision,cue,confidence") and "needs_review" in csv_text
    assert run_cli(["orient", str(lib), mode, "--force", "--report", str(reports / "third")]) == 0
    assert library_hash(lib) == first  # forced: analysed again, same answer, still nothing written
    assert all(r["action"] == "already_set" for r in json.loads((reports / "third.json").read_text()))


def _xmp_of(path: Path) -> bytes:
    data = path.read_bytes()
    start, end = inspect(data, parse_header(data)).xmp_span
    return data[start:end]


def test_rejected_photos_are_left_alone_and_flagged_for_review(tmp_path, monkeypatch):
    monkeypatch.setattr(cli, "get_detector", lambda config: FakeDetector(()))
    lib = tmp_path / "lib"
    make_library(lib)
    before = library_hash(lib)
    assert run_cli(["orient", str(lib), "--write", "--report", str(tmp_path / "r")]) == 0
    assert library_hash(lib) == before
    rows = json.loads((tmp_path / "r.json").read_text())
    assert all(r["needs_review"] and r["decision"] == "rejected" for r in rows)


# --- real files ------------------------------------------------------------------------------------

# file -> [(source kind, value)], from orientation/PROVENANCE.txt
KNOWN_SOURCES = {
    "exiv2__exiv2-bug922.tif": [("exif-ifd0", 6)],
    "photoprism__rotate_6.tiff": [("exif-ifd0", 6)],
    **{f"pillow__g4_orientation_{v}.tif": [("exif-ifd0", v)] for v in range(1, 9)},
    "photoprism__orientation.png": [("exif-ifd0", 1)],
    "photoprism__rotate_6.png": [("exif-ifd0", 6)],
    "pillow__exif.png": [("exif-ifd0", 1)],
    "pillow__xmp_tags_orientation.png": [("xmp-embedded", 3)],
    "exiv2__exiv2-bug937.jpg": [("exif-ifd0", 1), ("xmp-embedded", 1)],
    "photoprism__iphone_15_pro.heic": [("heif-transform", 6), ("heif-exif", 6)],
    "photoprism__iphone_7.heic": [("heif-transform", 1), ("heif-exif", 6)],
    "pillowheif__pug.heic": [("heif-transform", 1), ("heif-exif", 1)],
    "libheif__example.heic": [("heif-transform", 1)],
    "pillow__rot1mir0.avif": [("heif-transform", 5)],
    "pillow__xmp_tags_orientation.avif": [("heif-transform", 1), ("xmp-embedded", 3)],
}


@needs_formats
@pytest.mark.parametrize("name", sorted(KNOWN_SOURCES))
def test_real_files_state_what_their_provenance_says(name):
    data = (FORMATS / name).read_bytes()
    insp = inspect(data, parse_header(data, name))
    assert [(s.kind, s.value) for s in insp.sources] == KNOWN_SOURCES[name]
    conflicting = name in ("photoprism__iphone_7.heic", "pillow__xmp_tags_orientation.avif")
    assert bool(insp.conflicts()) == conflicting


@needs_formats
@pytest.mark.parametrize("name", ["exiv2__exiv2-bug922.tif", "photoprism__rotate_6.tiff",
                                  *[f"pillow__g4_orientation_{v}.tif" for v in range(1, 9)]])
def test_real_tiffs_are_patched_in_place(name):
    before = (FORMATS / name).read_bytes()
    after = write_tiff_orientation(before, 8 if not name.endswith("_8.tif") else 3)
    assert len(after) == len(before) and len(differing(before, after)) == 1
    assert Image.open(io.BytesIO(after)).getexif()[274] in (8, 3)


@needs_formats
@needs_exiftool
@pytest.mark.parametrize("name", ["photoprism__orientation.png", "photoprism__rotate_6.png", "pillow__exif.png",
                                  "pillow__xmp_tags_orientation.png"])
def test_real_pngs_get_their_exif_chunk_before_idat(name):
    before = (FORMATS / name).read_bytes()
    after = write_png_orientation(before, 8, update_xmp=name.startswith("pillow__xmp"))
    types = _chunk_types(after)
    assert types.count(b"eXIf") == 1 and types.index(b"eXIf") < types.index(b"IDAT")
    insp = inspect(after, parse_header(after))
    assert {s.value for s in insp.sources if s.applied_by_viewers} == {8} and not insp.conflicts()
    idat = lambda d: [d[s:e] for k, _, s, e in png_chunks(d) if k == b"IDAT"]  # noqa: E731
    assert idat(after) == idat(before)


@needs_formats
def test_real_heic_is_never_written_and_gets_the_sidecar_the_exif_item_agrees_with():
    """iphone_7.heic: EXIF 6 but no irot, so it is displayed sideways; a turn of 90 found on the displayed
    image becomes a sidecar with 6 (what the EXIF item says), and the conflict is reported."""
    data = (FORMATS / "photoprism__iphone_7.heic").read_bytes()
    outcome = orient_file(data, FakeDetector((90,)), filename="iphone_7.heic")
    assert outcome.photo is None and outcome.sidecar_name == "iphone_7.heic.xmp"
    assert read_packet(outcome.sidecar).value == 6 and outcome.report.conflicts
    arrow = (FORMATS / "pillowheif__arrow.heic").read_bytes()
    kept = orient_file(arrow, FakeDetector((0,)), filename="arrow.heic")  # its irot (6) is its own orientation
    assert kept.report.decision == "not_analysed" and kept.report.action == "kept_existing" and kept.sidecar is None
    upright = orient_file(arrow, FakeDetector((0,)), force=True, filename="arrow.heic")
    assert upright.report.action == "already_set" and upright.sidecar is None
    assert upright.report.existing_orientation == 6 and upright.report.orientation == 6


@needs_formats
@pytest.mark.parametrize("name,value", [("photoprism__iphone_7.xmp", 6), ("photoprism__ladybug.xmp", 1),
                                        ("photoprism__photoshop.xmp", 0), ("photoprism__digikam_aurora.jpg.xmp", 1),
                                        ("photoprism__darktable_aurora.jpg.xmp", None),
                                        ("exiftool__XMP.xmp", 1), ("photoprism__canon_eos_6d.xmp", 1)])
def test_real_sidecars_are_read_and_patched_in_place(name, value):
    data = (FORMATS / name).read_bytes()
    assert read_packet(data).value == value
    patched = patch_packet(data, 8)
    if value is None:
        assert patched is None  # darktable keeps orientation in its history: the property must be added
    else:
        assert len(patched) == len(data) and len(differing(data, patched)) <= 1 and read_packet(patched).value == 8


@needs_formats
@needs_exiftool
def test_real_darktable_sidecar_gets_the_property_added_by_exiftool(tmp_path):
    data = (FORMATS / "photoprism__darktable_aurora.jpg.xmp").read_bytes()
    out = sidecar_bytes(6, data)
    assert read_packet(out).value == 6 and b"darktable:history" in out


@needs_formats
def test_real_library_walk_twice(tmp_path, monkeypatch):
    """A copy of the real formats folder as a library, sidecar mode: the first run writes sidecars only,
    the second writes nothing."""
    monkeypatch.setattr(cli, "get_detector", lambda config: FakeDetector((180,)))
    lib = tmp_path / "lib"
    lib.mkdir()
    for name in ("exiv2__exiv2-bug922.tif", "pillow__g4_orientation_1.tif", "photoprism__orientation.png",
                 "libheif__example.heic", "pillow__rot1mir0.avif", "photoprism__ladybug.jpg"):
        shutil.copy(FORMATS / name, lib / name)
    assert run_cli(["orient", str(lib), "--sidecar", "--report", str(tmp_path / "r1")]) == 0
    first = library_hash(lib)
    rows = {Path(r["path"]).name: r for r in json.loads((tmp_path / "r1.json").read_text())}
    assert rows["exiv2__exiv2-bug922.tif"]["action"] == "skipped: already tagged (6)"
    assert rows["pillow__rot1mir0.avif"]["action"] == "skipped: already tagged (5)"
    assert rows["libheif__example.heic"]["action"] == "written 3 to sidecar libheif__example.heic.xmp"
    assert read_packet((lib / "photoprism__ladybug.jpg.xmp").read_bytes()).value == 3
    assert run_cli(["orient", str(lib), "--sidecar", "--report", str(tmp_path / "r2")]) == 0
    assert library_hash(lib) == first
