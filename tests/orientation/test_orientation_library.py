"""A photo batch as a library: in blocks on Ray it reports what the photos one at a time report, in their order, with
progress counts and the time left; an attempt run again analyses only what the last one did not finish."""
from __future__ import annotations

import json
from dataclasses import asdict

import pytest

from harness.photos import asymmetric_image
from tests.orientation.builders import FakeDetector, encode, jpeg
from tests.orientation.test_orientation_text import text_page, turned
from workers.orientation import blocks
from workers.orientation.blocks import BLOCK_MAX_PHOTOS, block_sizes
from workers.orientation.exif import write_orientation
from workers.runtime import JobSpec, execute_job, results_prefix
from workers.storage import DirectoryBlobStore
from workers.workarea import work_prefix


def library() -> list[tuple[str, bytes]]:
    """A small mixed batch: a page of text turned a quarter (decided by its text, where tesseract is installed: a
    fixed file), photos with nothing to decide (left for the review page), a broken file, one already
    tagged, a PNG."""
    return [
        ("scan.jpg", jpeg(turned(text_page(), 90))),
        *[(f"plain {i}.jpg", jpeg(asymmetric_image(120 + 40 * i, 200))) for i in range(3)],
        ("broken.jpg", jpeg()[:300]),
        ("tagged.jpg", write_orientation(jpeg(), 8)),
        ("drawing.png", encode(asymmetric_image(90, 160), ".png")),
    ]


def put_batch(store: DirectoryBlobStore, job_id: str, photos: list[tuple[str, bytes]]) -> JobSpec:
    inputs, meta = {}, {}
    for i, (filename, data) in enumerate(photos):
        name = f"photo-{i:04d}"
        inputs[name] = f"jobs/{job_id}/inputs/{name}"
        store.put(inputs[name], data)
        meta[name] = {"filename": filename, "size": len(data)}
    return JobSpec(job_id, "orientation.batch", {"force": False}, inputs, meta, store_url=store.url)


def published(store: DirectoryBlobStore, job_id: str) -> tuple[list[dict], dict[str, bytes]]:
    """The job's report entries (the time each took left out) and its other result files."""
    prefix = results_prefix(job_id) + "/"
    entries = json.loads(store.read(prefix + "report.json"))
    for entry in entries:
        if entry["report"]:
            entry["report"].pop("elapsed_ms")
    files = {key[len(prefix):]: store.read(key) for key in store.list(prefix) if not key.endswith("report.json")}
    return entries, files


def test_a_batch_in_blocks_on_ray_reports_what_the_photos_one_at_a_time_do(ray_local, tmp_path):
    from workers.ray_tasks import run_job_task

    store = DirectoryBlobStore(tmp_path / "store")
    photos = library()
    events = [ray_local.get(ref) for ref in run_job_task.remote(asdict(put_batch(store, "on-ray", photos)))]
    assert events[-1]["type"] == "succeeded", events[-1]
    in_turn = list(execute_job(put_batch(store, "in-turn", photos)))  # this process, one block after another
    assert in_turn[-1]["type"] == "succeeded", in_turn[-1]

    entries, files = published(store, "on-ray")
    assert (entries, files) == published(store, "in-turn")
    assert [e["filename"] for e in entries] == [name for name, _ in photos] and [e["index"] for e in entries] == [
        *range(len(photos))]
    assert entries[4]["error"]["code"] == "truncated_image" and entries[4]["report"] is None  # the others went on
    assert entries[5]["report"]["existing_orientation"] == 8 and entries[5]["fixed_file"] is None
    if entries[0]["report"]["text"]["status"] == "ran":  # tesseract installed: the page decided by its text
        assert entries[0]["report"]["cue"] == "text" and entries[0]["fixed_file"] == "fixed/0000-scan.jpg"
    assert events[-1]["manifest"]["summary"]["photos"] == len(photos)
    assert store.list(work_prefix("on-ray")) == []  # published: the work area is gone

    progress = [e for e in events if e["type"] == "progress"]
    assert [e["done"] for e in progress] == [*range(1, len(photos) + 1)]  # one event per photo, counted
    assert all(e["total"] == len(photos) and e["eta_s"] >= 0 for e in progress) and progress[-1]["eta_s"] == 0
    assert progress[4]["stage"].startswith("photo 5/7 ") and progress[-1]["fraction"] == 1.0


def test_an_attempt_run_again_analyses_only_the_photos_the_last_one_did_not_finish(tmp_path, monkeypatch):
    detector = FakeDetector((90,))  # every photo turned: each gets a fixed file
    monkeypatch.setattr(blocks, "get_detector", lambda config: detector)
    store = DirectoryBlobStore(tmp_path / "store")
    photos = [(f"p{i}.jpg", jpeg(asymmetric_image(60 + 4 * i, 100))) for i in range(12)]
    real = blocks.process_photo
    analysed: list[int] = []

    def crash_at_the_eighth(task, photo, *args):
        if photo.index == 7:
            raise RuntimeError("the worker was lost")
        analysed.append(photo.index)
        return real(task, photo, *args)

    monkeypatch.setattr(blocks, "process_photo", crash_at_the_eighth)
    spec = put_batch(store, "j", photos)
    first = list(execute_job(spec))
    assert first[-1]["type"] == "failed" and "the worker was lost" in first[-1]["error"]
    # one CPU, 12 photos: blocks of 3; the third block failed at its second photo
    assert block_sizes(12, 1) == [3, 3, 3, 3] and analysed == [0, 1, 2, 3, 4, 5, 6]

    analysed.clear()
    monkeypatch.setattr(blocks, "process_photo", lambda task, photo, *args: (analysed.append(photo.index),
                                                                            real(task, photo, *args))[1])
    second = list(execute_job(JobSpec(**{**asdict(spec), "attempt": 2})))
    assert second[-1]["type"] == "succeeded", second[-1]
    assert analysed == [6, 7, 8, 9, 10, 11]  # the finished blocks are not analysed again
    progress = [e for e in second if e["type"] == "progress"]
    assert progress[0]["stage"] == "6 of 12 photos done by an earlier attempt" and progress[0]["done"] == 6
    assert [e["done"] for e in progress[1:]] == [*range(7, 13)]

    fresh = list(execute_job(put_batch(store, "fresh", photos)))
    assert fresh[-1]["type"] == "succeeded"
    assert published(store, "j") == published(store, "fresh")  # the same report and the same fixed files
    assert len([f for f in published(store, "j")[1] if f.startswith("fixed/")]) == 12


@pytest.mark.parametrize("photos,workers,sizes", [
    (1, 2, [1]), (4, 2, [1, 1, 1, 1]), (12, 1, [3, 3, 3, 3]), (20, 2, [3] * 6 + [2]),
    (500, 2, [BLOCK_MAX_PHOTOS] * 59 + [7] * 4), (500, 64, [2] * 250), (0, 2, []),
])
def test_blocks_are_several_per_cpu_never_large_and_as_equal_as_can_be(photos, workers, sizes):
    assert block_sizes(photos, workers) == sizes
