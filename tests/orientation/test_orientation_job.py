"""The batch job with a fake context, and the ``sweepcast orient`` command."""
from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from harness.photos import asymmetric_image
from tests.orientation.builders import FakeDetector, encode, exiftool_runs, jpeg
from workers.common.jobctx import JobInputError
from workers.fanout import InProcess
from workers.orientation import blocks, cli, job
from workers.storage import DirectoryBlobStore
from workers.workarea import WorkArea

HAS_EXIFTOOL = exiftool_runs()
from workers.orientation.exif import read_exif, write_orientation
from workers.orientation.job import OrientationBatchParams, run_orientation_batch, sanitize_filename
from workers.settings import WorkerSettings, worker_settings


@dataclass
class FakeContext:
    """A job context over a folder: inputs in a blob store there, results in ``out/``, fan-outs run in turn here."""

    root: Path
    params: dict[str, Any]
    inputs: dict[str, str] = field(default_factory=dict)
    input_meta: dict[str, dict[str, Any]] = field(default_factory=dict)
    job_id: str = "job-1"
    kind: str = "orientation.batch"
    events: list[tuple[float, str]] = field(default_factory=list)
    parallelism: int = 1

    @property
    def settings(self) -> WorkerSettings:  # read at each use: tests set the environment after making a context
        return worker_settings()

    @property
    def store(self) -> DirectoryBlobStore:
        return DirectoryBlobStore(self.root / "store")

    def add(self, name: str, filename: str, data: bytes) -> None:
        self.inputs[name] = f"in/{name}"
        self.store.put(self.inputs[name], data)
        self.input_meta[name] = {"filename": filename, "size": len(data)}

    def input_path(self, name: str) -> Path:
        return self.store.local_path(self.inputs[name])

    def read_input(self, name: str) -> bytes:
        return self.input_path(name).read_bytes()

    def work_area(self) -> WorkArea:
        return WorkArea.for_job(self.store, self.job_id, self.inputs)

    def fanout(self) -> InProcess:
        return InProcess(parallelism=self.parallelism)

    def adopt_result(self, name: str, work_name: str, size: int) -> None:
        data = self.store.read(self.work_area().key(work_name))
        assert len(data) == size
        self.write_result(name, data)

    def result_path(self, name: str) -> Path:
        path = self.root / "out" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def write_result(self, name: str, data: bytes) -> None:
        self.result_path(name).write_bytes(data)

    def progress(self, fraction: float, stage: str, **counts) -> None:
        self.events.append((fraction, stage))


@pytest.fixture
def fake_detector(monkeypatch):
    """Every photo is found turned: rotate 90 degrees clockwise (EXIF 6)."""
    detector = FakeDetector((90,))
    monkeypatch.setattr(blocks, "get_detector", lambda config: detector)
    monkeypatch.setattr(cli, "get_detector", lambda config: detector)
    return detector


def test_batch_with_one_corrupt_photo_among_good_ones(tmp_path, fake_detector):
    good = jpeg()
    ctx = FakeContext(tmp_path, {"force": False})
    ctx.add("photo-0000", "../../IMG 0001 (copy).JPG", good)
    ctx.add("photo-0001", "broken.jpg", good[:len(good) // 2])
    ctx.add("photo-0002", "scan.png", encode(asymmetric_image(), ".png"))
    ctx.add("photo-0003", "tagged.jpg", write_orientation(good, 8))

    summary = run_orientation_batch(ctx)

    assert {k: v for k, v in summary.items() if k not in ("written", "rotated", "decided_by_faces", "errors")} == {
        "photos": 4, "upright": 0, "rejected": 0, "not_analysed": 1, "decided_by_text": 0, "needs_review": 0,
        "reviewed": 0}
    assert summary["rotated"] == summary["decided_by_faces"] == (2 if HAS_EXIFTOOL else 1)
    assert summary["written"] == (2 if HAS_EXIFTOOL else 1) and summary["errors"] == (1 if HAS_EXIFTOOL else 2)
    assert [round(f, 2) for f, _ in ctx.events] == [0.25, 0.5, 0.75, 1.0]  # one event per photo
    assert "broken.jpg: error: truncated_image" in ctx.events[1][1]
    entries = json.loads((tmp_path / "out" / "report.json").read_text())
    assert [e["filename"] for e in entries] == ["../../IMG 0001 (copy).JPG", "broken.jpg", "scan.png", "tagged.jpg"]
    first, broken, png, tagged = entries
    assert first["report"]["orientation"] == 6 and first["fixed_file"] == "fixed/0000-IMG_0001_copy.jpg"
    fixed = (tmp_path / "out" / first["fixed_file"]).read_bytes()
    assert read_exif(fixed).orientation == 6
    assert broken["report"] is None and broken["error"]["code"] == "truncated_image"
    assert "truncated" in broken["error"]["message"]
    if HAS_EXIFTOOL:
        assert png["report"]["orientation"] == 6 and png["report"]["write"]["target"] == "png-exif"
        assert png["fixed_file"] == "fixed/0002-scan.png"
    else:
        assert png["error"]["code"] == "metadata_tool_unavailable" and "exiftool" in png["error"]["message"]
    assert tagged["report"]["action"] == "kept_existing" and tagged["fixed_file"] is None
    assert tagged["report"]["decision"] == "not_analysed" and fake_detector.seen == [(120, 200)] * 2  # never shown
    assert "0000-IMG_0001_copy.jpg" in [p.name for p in (tmp_path / "out" / "fixed").iterdir()]


def test_batch_force_and_report_only(tmp_path, fake_detector):
    ctx = FakeContext(tmp_path, {"force": True})
    ctx.add("photo-0000", "tagged.jpg", write_orientation(jpeg(), 8))
    assert run_orientation_batch(ctx)["written"] == 1

    ctx = FakeContext(tmp_path / "b", {"write": False})
    ctx.add("photo-0000", "a.jpg", jpeg())
    assert run_orientation_batch(ctx)["written"] == 0
    assert not (tmp_path / "b" / "out" / "fixed").exists()


def test_batch_params_are_validated():
    assert OrientationBatchParams.model_validate({}).model_dump() == {"force": False, "write": True, "sidecar": False,
                                                                      "method": "auto", "text": True}
    with pytest.raises(ValueError):
        OrientationBatchParams.model_validate({"text": "perhaps"})
    with pytest.raises(ValueError):
        OrientationBatchParams.model_validate({"force": True, "yunet_model": "/etc/passwd"})
    with pytest.raises(ValueError):
        OrientationBatchParams.model_validate({"method": "guess"})


def test_batch_without_photos_or_with_an_unconfigured_detector(tmp_path, monkeypatch):
    with pytest.raises(JobInputError, match="no photos"):
        run_orientation_batch(FakeContext(tmp_path, {}))
    monkeypatch.delenv(job.YUNET_MODEL_ENV, raising=False)
    ctx = FakeContext(tmp_path, {"method": "yunet"})
    ctx.add("photo-0000", "a.jpg", jpeg())
    with pytest.raises(JobInputError, match="YuNet model"):
        run_orientation_batch(ctx)


@pytest.mark.parametrize("name,expected", [
    ("IMG_1234.JPG", "IMG_1234"), ("../../etc/passwd", "passwd"), ("C:\\photos\\a b.jpeg", "a_b"),
    (".hidden.jpg", "hidden"), ("....", "photo"), ("été 2024.jpg", "t_2024"), ("x" * 300 + ".jpg", "x" * 80),
])
def test_sanitize_filename(name, expected):
    assert sanitize_filename(name) == expected


# --- CLI -------------------------------------------------------------------------------------------

def run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="sweepcast")
    cli.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args([*argv, "--jobs", "1"])  # in this process: the tests' fake detectors stay in it
    return args.func(args)


def test_cli_dry_run_changes_nothing_and_prints_a_table(tmp_path, fake_detector, capsys):
    photo = tmp_path / "a.jpg"
    photo.write_bytes(jpeg())
    before = photo.read_bytes()
    assert run(["orient", str(photo)]) == 0
    out = capsys.readouterr().out
    assert photo.read_bytes() == before
    assert "rotated" in out and "would write 6 to EXIF" in out and "1 photos: 0 upright, 1 rotated" in out


def test_cli_write_tags_files_in_folders(tmp_path, fake_detector, capsys):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "a.jpg").write_bytes(jpeg())
    (tmp_path / "notes.txt").write_text("not a photo")
    assert run(["orient", str(tmp_path), "--write"]) == 0
    out = capsys.readouterr().out
    assert read_exif((tmp_path / "sub" / "a.jpg").read_bytes()).orientation == 6
    assert "written 6 to EXIF" in out and "notes.txt" not in out


def test_cli_json_output(tmp_path, fake_detector, capsys):
    (tmp_path / "a.jpg").write_bytes(jpeg())
    assert run(["orient", str(tmp_path / "a.jpg"), "--json"]) == 0
    [entry] = json.loads(capsys.readouterr().out)
    assert entry["report"]["orientation"] == 6 and entry["action"] == "would write 6 to EXIF"


def test_cli_bad_files_and_paths_exit_2(tmp_path, fake_detector, capsys):
    good, bad = tmp_path / "good.jpg", tmp_path / "bad.jpg"
    good.write_bytes(jpeg())
    bad.write_bytes(b"")
    assert run(["orient", str(good), str(bad), "--write"]) == 2
    captured = capsys.readouterr()
    assert read_exif(good.read_bytes()).orientation == 6  # the good file is still processed
    assert "bad.jpg: the file is empty" in captured.err and "Traceback" not in captured.err
    assert run(["orient", str(tmp_path / "missing.jpg")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_cli_yunet_without_a_model_exits_2(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv(job.YUNET_MODEL_ENV, raising=False)
    (tmp_path / "a.jpg").write_bytes(jpeg())
    assert run(["orient", str(tmp_path / "a.jpg"), "--method", "yunet"]) == 2
    assert "YuNet model" in capsys.readouterr().err
    assert run(["orient", str(tmp_path / "a.jpg"), "--yunet", str(tmp_path / "none.onnx")]) == 2
    assert "not found" in capsys.readouterr().err


def test_workers_use_the_named_model_else_the_installed_one(tmp_path, monkeypatch):
    from workers.common.models import MODELS_DIR_ENV, YUNET
    from workers.orientation.detect import detector_config
    from workers.settings import worker_settings

    monkeypatch.delenv(job.YUNET_MODEL_ENV, raising=False)
    monkeypatch.setenv(MODELS_DIR_ENV, str(tmp_path))

    def worker_config():  # as a batch job builds it from its context's settings
        settings = worker_settings()
        return detector_config(settings, settings.models_dir)

    assert worker_config().yunet_model is None  # nothing installed yet
    (tmp_path / YUNET.filename).write_bytes(b"model")
    assert worker_config().yunet_model == tmp_path / YUNET.filename
    monkeypatch.setenv(job.YUNET_MODEL_ENV, "/elsewhere/yunet.onnx")
    assert worker_config().yunet_model == Path("/elsewhere/yunet.onnx")


def test_photos_left_for_review_are_counted_and_get_no_file(tmp_path, monkeypatch):
    detector = FakeDetector(())  # nothing decides: every photo needs a person
    monkeypatch.setattr(blocks, "get_detector", lambda config: detector)
    ctx = FakeContext(tmp_path, {"text": False})
    ctx.add("photo-0000", "wide.jpg", jpeg(asymmetric_image(600, 900)))
    ctx.add("photo-0001", "small.png", encode(asymmetric_image(120, 200), ".png"))
    summary = run_orientation_batch(ctx)
    assert summary["rejected"] == summary["needs_review"] == 2 and summary["reviewed"] == 0
    entries = json.loads((tmp_path / "out" / "report.json").read_text())
    assert all(e["review"] is None and e["fixed_file"] is None for e in entries)
    assert sorted(p.name for p in (tmp_path / "out").rglob("*") if p.is_file()) == ["report.json"]
