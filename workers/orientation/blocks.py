"""A photo batch in blocks: the unit of work the batch job fans out (:mod:`workers.fanout`) and resumes.

A block is a run of consecutive photos of the batch. :func:`analyse_block` runs in any process of the cluster: it
reads each photo from the job's inputs, analyses it (and tags it), writes the fixed file into the job's work area
(``files/<result name>``), then, last, its record ``blocks/<first>-<last>.json``: ``{"entries": [report.json entry,
...], "files": {result name: size}}``. A record present means the block is done: an attempt of the job run again (a
lost worker, a restart of the service) finds the records of the blocks an earlier attempt finished
(:func:`finished_photos`) and analyses only the other photos.

Blocks are sized by :func:`block_sizes`: several per CPU so that the last ones finish together, and at most
``BLOCK_MAX_PHOTOS`` photos so that a lost worker loses little and progress comes often.
"""
from __future__ import annotations

import contextlib
import json
import math
import re
from dataclasses import dataclass
from typing import Any, Iterator, Sequence

import cv2

from workers.orientation.detect import DetectorConfig, OrientationDetector, get_detector
from workers.common.errors import InputError
from workers.orientation.headers import sniff_format
from workers.orientation.metadata import WriteMode
from workers.orientation.orient import analyze, orient_file
from workers.workarea import WorkArea

BLOCK_MAX_PHOTOS = 8
"""Most photos in one block. A block costs about 2 ms to start as a Ray task and one small record written to the blob
store, against tens of milliseconds to seconds of CPU per photo, so even blocks of one photo would waste little;
what bounds the size is what a lost worker loses and how often progress comes. The detector is built once per worker
process, not per block (``get_detector`` keeps it), so the block size does not change its cost
(``python -m benchmarks.orientation_library --only blocks`` measures it)."""
BLOCKS_PER_WORKER = 4
"""Blocks per CPU at least, where the batch is large enough: the photos of a block are not shared out, so with a
single block per CPU the slowest one would leave the other CPUs idle at the end."""
RECORDS = "blocks"
FILES = "files"


@dataclass(frozen=True)
class PhotoRef:
    """One photo of the batch: its position (``index``, the report's order), input name and original file name."""

    index: int
    name: str
    filename: str


@dataclass(frozen=True)
class BlockTask:
    """What :func:`analyse_block` needs, all picklable: the photos, the job's work area, and the job's settings."""

    work: WorkArea
    photos: tuple[PhotoRef, ...]
    config: DetectorConfig
    force: bool
    write: bool
    mode: WriteMode
    max_pixels: int


def block_sizes(photos: int, workers: int) -> list[int]:
    """How many photos each block gets, in order: at least ``BLOCKS_PER_WORKER`` blocks per worker where there are
    enough photos, at most ``BLOCK_MAX_PHOTOS`` each, as equal as can be."""
    if photos <= 0:
        return []
    size = max(1, min(BLOCK_MAX_PHOTOS, math.ceil(photos / (BLOCKS_PER_WORKER * max(1, workers)))))
    count = math.ceil(photos / size)
    base, extra = divmod(photos, count)
    return [base + (i < extra) for i in range(count)]


def plan_blocks(photos: Sequence[PhotoRef], workers: int) -> list[tuple[PhotoRef, ...]]:
    """``photos`` cut into consecutive blocks (:func:`block_sizes`)."""
    blocks, start = [], 0
    for size in block_sizes(len(photos), workers):
        blocks.append(tuple(photos[start:start + size]))
        start += size
    return blocks


def analyse_block(task: BlockTask) -> dict[str, Any]:
    """Analyse (and tag) every photo of the block, write its files and then its record into the work area; the
    record. A photo that cannot be read gets its error in its entry; the block goes on."""
    detector = get_detector(task.config)  # built once per process
    files: dict[str, int] = {}
    with _one_opencv_thread():  # the CPUs are shared out by blocks: one thread each
        entries = [process_photo(task, photo, detector, files) for photo in task.photos]
    record = {"entries": entries, "files": files}
    task.work.put(record_name(task.photos), json.dumps(record).encode())
    return record


def record_name(photos: Sequence[PhotoRef]) -> str:
    return f"{RECORDS}/{photos[0].index:06d}-{photos[-1].index:06d}.json"


def finished_photos(work: WorkArea) -> dict[int, tuple[dict[str, Any], dict[str, int]]]:
    """Photo index -> (its entry, the files of its block's record) for every photo whose block an earlier attempt
    finished (records that cannot be read are left out: their photos are analysed again)."""
    done: dict[int, tuple[dict[str, Any], dict[str, int]]] = {}
    for name in work.names(RECORDS):
        try:
            record = json.loads(work.get(name))
        except (ValueError, KeyError):  # unreadable, or deleted since it was listed
            continue
        for entry in record.get("entries", []):
            files = {f: size for f, size in record.get("files", {}).items() if f in files_of(entry)}
            done[int(entry["index"])] = (entry, files)
    return done


def files_of(entry: dict[str, Any]) -> set[str]:
    """The result files an entry names (its fixed file)."""
    return {entry["fixed_file"]} if entry.get("fixed_file") else set()


def process_photo(task: BlockTask, photo: PhotoRef, detector: OrientationDetector,
                  files: dict[str, int]) -> dict[str, Any]:
    """The report.json entry of one photo; its fixed file written to the work area (``files``: result name -> size,
    added to)."""
    index, filename = photo.index, photo.filename
    entry: dict[str, Any] = {"index": index, "input": photo.name, "filename": filename, "report": None,
                             "error": None, "fixed_file": None, "note": None, "review": None}

    def keep(name: str, data: bytes) -> str:
        files[name] = task.work.put(f"{FILES}/{name}", data)
        return name

    try:
        data = task.work.read_input(photo.name)
        fmt = sniff_format(data, filename)
        if task.write:
            outcome = orient_file(data, detector, task.force, task.max_pixels, filename, mode=task.mode)
            report = outcome.report
            stem = fixed_name(index, filename, fmt)
            if outcome.photo is not None:
                entry["fixed_file"] = keep(stem, outcome.photo)
            elif outcome.sidecar is not None:
                entry["fixed_file"] = keep(stem + ".xmp", outcome.sidecar)
            if report.write is not None and report.write.note:
                entry["note"] = report.write.note
        else:
            report = analyze(data, detector, task.max_pixels, filename, mode=task.mode)
        entry["report"] = report.model_dump(mode="json")
    except InputError as exc:  # the photo's own problem (ExifTool's included): this photo fails, the others go on
        entry["error"] = {"code": exc.code, "message": str(exc)}
    return entry


@contextlib.contextmanager
def _one_opencv_thread() -> Iterator[None]:
    """OpenCV on one thread meanwhile (this process's setting as it was afterwards: a Ray worker runs other jobs)."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(threads)


def fixed_name(index: int, filename: str, fmt: str) -> str:
    """The result name of photo ``index``'s fixed file (its sidecar adds ``.xmp``)."""
    return f"fixed/{index:04d}-{sanitize_filename(filename)}.{_EXT[fmt]}"


_EXT = {"jpeg": "jpg", "webp": "webp", "tiff": "tif", "png": "png", "heif": "heic", "avif": "avif", "raw": "raw"}


def sanitize_filename(filename: str, limit: int = 80) -> str:
    """A safe file stem from an uploaded name: last path component, no extension, [A-Za-z0-9._-] only."""
    base = re.split(r"[\\/]", filename)[-1]
    stem = base.rsplit(".", 1)[0] if "." in base.lstrip(".") else base
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", stem).strip("._-")
    return safe[:limit] or "photo"
