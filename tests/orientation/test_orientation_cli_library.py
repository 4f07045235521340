"""``sweepcast orient`` over a library: several processes report what one does, in the files' order; a run remembers
what it decided, so an interrupted run goes on where it stopped and the next run analyses nothing it already
decided with the same bytes."""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
from pathlib import Path

import pytest

from harness.photos import asymmetric_image
from tests.orientation.builders import FakeDetector, jpeg
from tests.orientation.test_orientation_text import text_page, turned
from workers.orientation import cli
from workers.orientation.exif import read_exif, write_orientation


def run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="sweepcast")
    cli.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def photos(root: Path, count: int = 5) -> list[Path]:
    root.mkdir(parents=True, exist_ok=True)
    paths = [root / f"IMG_{i:04d}.jpg" for i in range(count)]
    for i, path in enumerate(paths):
        path.write_bytes(jpeg(asymmetric_image(80 + 8 * i, 120)))
    return paths


def hashes(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def rows(stem: Path, root: Path) -> list[dict]:
    """The report's rows, paths relative to the library (the time each photo took left out)."""
    out = json.loads(stem.with_name(stem.name + ".json").read_text())
    for row in out:
        row["path"] = str(Path(row["path"]).relative_to(root))
    return out


@pytest.fixture
def fake(monkeypatch):
    """Every photo found turned 90 degrees clockwise (EXIF 6), in this process (``--jobs 1``)."""
    detector = FakeDetector((90,))
    monkeypatch.setattr(cli, "get_detector", lambda config: detector)
    return detector


def test_two_processes_report_and_write_what_one_does(tmp_path):
    library = tmp_path / "one"
    photos(library / "holiday", 3)
    (library / "scan.jpg").write_bytes(jpeg(turned(text_page(), 90)))  # decided by its text where tesseract is
    (library / "tagged.jpg").write_bytes(write_orientation(jpeg(), 8))
    (library / "broken.jpg").write_bytes(jpeg()[:300])
    shutil.copytree(library, tmp_path / "two")
    before = hashes(library)

    assert run(["orient", str(library), "--write", "--jobs", "1", "--report", str(tmp_path / "r1")]) == 2
    assert run(["orient", str(tmp_path / "two"), "--write", "--jobs", "2", "--report", str(tmp_path / "r2")]) == 2

    one, two = rows(tmp_path / "r1", library), rows(tmp_path / "r2", tmp_path / "two")
    for row in one + two:
        row["written_to"] = [str(Path(p).name) for p in row["written_to"]]
        if row["report"]:
            row["report"].pop("elapsed_ms", None)
    assert one == two
    assert [r["path"] for r in one] == ["broken.jpg", "holiday/IMG_0000.jpg", "holiday/IMG_0001.jpg",
                                        "holiday/IMG_0002.jpg", "scan.jpg", "tagged.jpg"]  # the files' order
    assert one[0]["error"] and one[-1]["action"] == "skipped: already tagged (8)"
    assert hashes(library) == hashes(tmp_path / "two")
    if one[4]["cue"] == "text":
        assert hashes(library)["scan.jpg"] != before["scan.jpg"] and one[4]["written_to"] == ["scan.jpg"]


def test_an_interrupted_run_goes_on_where_it_stopped(tmp_path, monkeypatch, capsys):
    paths = photos(tmp_path / "lib", 6)
    report = tmp_path / "report"

    class StoppedAtTheFourth(FakeDetector):
        def upright_faces(self, gray):
            if len(self.seen) == 3:
                raise KeyboardInterrupt  # Ctrl-C while the fourth photo is analysed
            return super().upright_faces(gray)

    monkeypatch.setattr(cli, "get_detector", lambda config: StoppedAtTheFourth((90,)))
    assert run(["orient", str(tmp_path / "lib"), "--jobs", "1", "--report", str(report)]) == 130
    err = capsys.readouterr().err
    state = tmp_path / "report.state.jsonl"
    assert "interrupted after 3 of 6 photos" in err and str(state) in err
    assert len(state.read_text().splitlines()) == 3 and not report.with_name("report.json").exists()

    detector = FakeDetector((90,))
    monkeypatch.setattr(cli, "get_detector", lambda config: detector)
    assert run(["orient", str(tmp_path / "lib"), "--jobs", "1", "--report", str(report)]) == 0
    assert len(detector.seen) == 3  # only the photos the first run did not finish
    out = rows(report, tmp_path / "lib")
    assert [r["action"] for r in out] == ["unchanged since the last run: would write 6 to EXIF"] * 3 + [
        "would write 6 to EXIF"] * 3
    assert all(r["orientation"] == 6 for r in out) and [r["path"] for r in out] == [p.name for p in paths]

    detector.seen.clear()
    assert run(["orient", str(tmp_path / "lib"), "--jobs", "1", "--report", str(report), "--no-resume"]) == 0
    assert len(detector.seen) == 6  # started over


def test_a_photo_left_for_review_is_not_analysed_again_until_its_bytes_change(tmp_path, monkeypatch):
    detector = FakeDetector(())  # nothing decides: every photo rejected
    monkeypatch.setattr(cli, "get_detector", lambda config: detector)
    paths = photos(tmp_path / "lib", 4)
    assert run(["orient", str(tmp_path / "lib"), "--write", "--jobs", "1"]) == 0
    assert len(detector.seen) == 4
    [state] = (Path(os.environ["XDG_CACHE_HOME"]) / "sweepcast" / "orient").glob("*.state.jsonl")  # not in the library
    assert sorted(p.name for p in (tmp_path / "lib").iterdir()) == [p.name for p in paths]

    detector.seen.clear()
    paths[2].write_bytes(jpeg(asymmetric_image(300, 200)))  # edited since
    assert run(["orient", str(tmp_path / "lib"), "--write", "--jobs", "1"]) == 0
    assert len(detector.seen) == 1
    assert len(state.read_text().splitlines()) == 4  # compacted: the edited photo's old row is gone


def test_photos_tagged_by_a_run_are_recognised_by_their_new_bytes(tmp_path, fake):
    """With --force every photo is analysed even when tagged, unless a run remembers its bytes: the bytes it wrote."""
    photos(tmp_path / "lib", 3)
    args = ["orient", str(tmp_path / "lib"), "--write", "--force", "--jobs", "1", "--report", str(tmp_path / "r")]
    assert run(args) == 0
    written = hashes(tmp_path / "lib")
    assert len(fake.seen) == 3 and all(read_exif((tmp_path / "lib" / n).read_bytes()).orientation == 6
                                       for n in written)
    fake.seen.clear()
    assert run(args) == 0
    assert fake.seen == [] and hashes(tmp_path / "lib") == written
    assert {r["action"] for r in rows(tmp_path / "r", tmp_path / "lib")} == {
        "unchanged since the last run: written 6 to EXIF"}


def test_a_dry_run_does_not_spare_the_writes_of_the_next_run(tmp_path, fake):
    photos(tmp_path / "lib", 2)
    assert run(["orient", str(tmp_path / "lib"), "--jobs", "1"]) == 0
    fake.seen.clear()
    assert run(["orient", str(tmp_path / "lib"), "--write", "--jobs", "1"]) == 0
    assert len(fake.seen) == 2  # what the dry run would write is written now: analysed again
    assert all(read_exif(p.read_bytes()).orientation == 6 for p in (tmp_path / "lib").iterdir())


def test_jobs_must_be_positive(tmp_path, capsys):
    with pytest.raises(SystemExit):
        run(["orient", str(tmp_path), "--jobs", "0"])
    assert "must be at least 1" in capsys.readouterr().err


def test_a_photo_unchanged_since_a_run_is_not_even_read_and_one_moved_is_read_once(tmp_path, fake, monkeypatch):
    from workers.orientation import library

    paths = photos(tmp_path / "lib", 3)
    assert run(["orient", str(tmp_path / "lib"), "--jobs", "1"]) == 0
    real, reads = library._read, []
    monkeypatch.setattr(library, "_read", lambda path: (reads.append(path.name), real(path))[1])
    fake.seen.clear()
    assert run(["orient", str(tmp_path / "lib"), "--jobs", "1"]) == 0
    assert reads == [] and fake.seen == []  # same size and modification time: not read
    paths[1].rename(tmp_path / "lib" / "moved.jpg")
    assert run(["orient", str(tmp_path / "lib"), "--jobs", "1"]) == 0
    assert reads == ["moved.jpg"] and fake.seen == []  # read to recognise its bytes, not analysed
    assert run(["orient", str(tmp_path / "lib"), "--jobs", "1"]) == 0
    assert reads == ["moved.jpg"]  # remembered where it is now


def test_copies_of_one_photo_in_several_albums_are_each_remembered_where_they_are(tmp_path, fake, monkeypatch):
    from workers.orientation import library

    [original] = photos(tmp_path / "lib" / "2024", 1)
    for album in ("holiday", "best of"):  # the same bytes, three places (a library's usual duplicates)
        (tmp_path / "lib" / album).mkdir()
        shutil.copy2(original, tmp_path / "lib" / album / original.name)
    report = ["--report", str(tmp_path / "report")]
    assert run(["orient", str(tmp_path / "lib"), "--jobs", "1", *report]) == 0
    real, reads = library._read, []
    monkeypatch.setattr(library, "_read", lambda path: (reads.append(path), real(path))[1])

    def no_engine(config):
        raise AssertionError("the engine was built for a library with nothing left to analyse")

    monkeypatch.setattr(cli, "get_detector", no_engine)
    for _ in range(2):  # the state file as the first run left it, then as a resumed run compacts it
        assert run(["orient", str(tmp_path / "lib"), "--jobs", "1", *report]) == 0
        assert reads == []  # no copy read again: each place has its own size and time
        assert [row["decision"] for row in rows(tmp_path / "report", tmp_path / "lib")] == ["rotated"] * 3


def test_a_photo_named_twice_is_analysed_once(tmp_path, fake):
    [path] = photos(tmp_path / "lib", 1)
    assert run(["orient", str(tmp_path / "lib"), str(path), "--jobs", "1", "--report", str(tmp_path / "r")]) == 0
    assert len(fake.seen) == 1 and len(rows(tmp_path / "r", tmp_path / "lib")) == 1


def test_a_library_already_done_does_not_build_the_engine_and_a_changed_text_cue_is_a_new_engine(tmp_path, fake,
                                                                                                 monkeypatch):
    photos(tmp_path / "lib", 3)
    report = ["--report", str(tmp_path / "report")]  # the state is kept beside it
    assert run(["orient", str(tmp_path / "lib"), "--jobs", "1", *report]) == 0
    assert len(fake.seen) == 3

    def no_engine(config):
        raise AssertionError("the engine was built for a library with nothing left to analyse")

    monkeypatch.setattr(cli, "get_detector", no_engine)
    assert run(["orient", str(tmp_path / "lib"), "--jobs", "1", *report]) == 0
    assert [row["decision"] for row in rows(tmp_path / "report", tmp_path / "lib")] == ["rotated"] * 3

    monkeypatch.setattr(cli, "get_detector", lambda config: fake)
    fake.seen.clear()
    assert run(["orient", str(tmp_path / "lib"), "--jobs", "1", "--no-text", *report]) == 0  # another engine
    assert len(fake.seen) == 3


def test_a_yunet_model_that_cannot_be_loaded_is_said_when_a_photo_needs_it(tmp_path, capsys):
    photos(tmp_path / "lib", 1)
    broken = tmp_path / "face_detection_yunet_2023mar.onnx"
    broken.write_bytes(b"not a model")
    assert run(["orient", str(tmp_path / "lib"), "--jobs", "1", "--yunet", str(broken)]) == 2
    assert "cannot load the YuNet model" in capsys.readouterr().err


def test_a_word_list_changed_since_a_run_makes_the_next_run_analyse_again(tmp_path, fake):
    lists = tmp_path / "dict"
    lists.mkdir()
    (lists / "words").write_text("hello\nworld\n")
    photos(tmp_path / "lib", 2)
    command = ["orient", str(tmp_path / "lib"), "--jobs", "1", "--wordlists", str(lists)]
    assert run(command) == 0
    fake.seen.clear()
    assert run(command) == 0
    assert fake.seen == []  # nothing changed: nothing analysed
    (lists / "words").write_text("hello\nworld\norientation\n")  # the text cue now knows another word
    assert run(command) == 0
    assert len(fake.seen) == 2
