"""Frames from the user's media: a video (any format PyAV/FFmpeg decodes), a zip of ordered
still images, or a folder of them; frame selection, blur rejection, resizing, undistortion.

Frames stream through :func:`select_frames` one at a time, so a long video never sits in memory.
"""
from __future__ import annotations

import math
import re
import zipfile
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import av
import cv2
import numpy as np

from workers.common import images
from workers.common.jobctx import JobInputError
from workers.common.safezip import SafeZip

from .calibration import Intrinsics
from .matching import global_shift

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
_THUMB = 320


@dataclass(frozen=True)
class Frame:
    """One selected frame: ``image`` (H, W, 3) uint8 BGR and ``gray`` (H, W) uint8 at the working
    resolution (undistorted when distortion was given); ``index`` counts decoded frames from 0;
    ``time`` in seconds (None for stills)."""

    index: int
    time: float | None
    name: str
    image: np.ndarray
    gray: np.ndarray


@dataclass(frozen=True)
class Skipped:
    """A decoded frame that frame selection left out: ``gray`` (H, W) uint8 at the working
    resolution (undistorted), None when the frame cannot be used at all; ``reason`` in words."""

    index: int
    time: float | None
    name: str
    gray: np.ndarray | None
    reason: str


@dataclass
class MediaSource:
    """Decoded frames of a video or an image sequence, (index, time, name, BGR image)."""

    kind: str
    """'video' or 'images'."""
    name: str
    count: int | None
    """Frames expected (None when the container does not say)."""
    _iter: Callable[[], Iterator[tuple[int, float | None, str, np.ndarray]]]
    errors: list[str] = field(default_factory=list)

    def __iter__(self) -> Iterator[tuple[int, float | None, str, np.ndarray]]:
        return self._iter()


def _natural_key(name: str) -> list:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def open_media(path: str | Path, name: str | None = None) -> MediaSource:
    """Open a video file, a zip of images or a folder of images (sorted by natural name order).

    ``name``: how messages call the media (the client's file name; default the path's last part,
    which for an uploaded job input is a storage key, never what the user sent).
    Raises JobInputError when the file is neither a decodable video nor an image archive.
    """
    path = Path(path)
    name = name or path.name
    if not path.exists():
        raise JobInputError(f"{name}: no such file")
    if path.is_dir():
        names = sorted((p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES), key=lambda p: _natural_key(p.name))
        if not names:
            raise JobInputError(f"the folder {name} holds no images ({', '.join(IMAGE_SUFFIXES)})")
        src = MediaSource("images", name, len(names), lambda: None)
        src._iter = lambda: _decode_stills(((p.name, p.read_bytes) for p in names), src)
        return src
    if zipfile.is_zipfile(path):
        return _open_zip(path, name)
    return _open_video(path, name)


def _open_zip(path: Path, name: str) -> MediaSource:
    """The images of a zip, checked by :class:`SafeZip` (member count, sizes, ratio, names) on
    opening and read with its cap; its limits come from the environment (the service's settings)."""
    label = f"the zip archive {name}"
    with SafeZip(path, label=label, error=JobInputError) as zf:
        names = [n for n in zf.names()
                 if Path(n).suffix.lower() in IMAGE_SUFFIXES and not Path(n).name.startswith(".")]
    if not names:
        raise JobInputError(f"{label} holds no images ({', '.join(IMAGE_SUFFIXES)})")
    names.sort(key=lambda n: _natural_key(Path(n).name))

    def items():
        with SafeZip(path, label=label, error=JobInputError) as zf:
            for n in names:
                yield Path(n).name, lambda n=n: zf.read(n)

    src = MediaSource("images", name, len(names), lambda: None)
    src._iter = lambda: _decode_stills(items(), src)
    return src


def still_files(path: str | Path, name: str | None = None) -> Iterator[tuple[str, bytes]]:
    """The image files of a zip or folder of stills as (file name, bytes), in the order
    :func:`open_media` decodes them (nothing for a video). The zip's limits apply as there."""
    path = Path(path)
    label = f"the zip archive {name or path.name}"
    if path.is_dir():
        files = sorted((p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES),
                       key=lambda p: _natural_key(p.name))
        for p in files:
            yield p.name, p.read_bytes()
    elif zipfile.is_zipfile(path):
        with SafeZip(path, label=label, error=JobInputError) as zf:
            names = [n for n in zf.names()
                     if Path(n).suffix.lower() in IMAGE_SUFFIXES and not Path(n).name.startswith(".")]
            names.sort(key=lambda n: _natural_key(Path(n).name))
            for n in names:
                yield Path(n).name, zf.read(n)


def read_stills(path: str | Path, names: list[str], name: str | None = None) -> dict[str, bytes]:
    """The bytes of the stills called ``names`` (file names as :func:`still_files` gives them) of a zip or folder,
    reading only those (a task that needs a few photos of a survey of thousands). The zip's limits apply as in
    :func:`open_media`; a name that is not there is left out."""
    path = Path(path)
    want = set(names)
    out: dict[str, bytes] = {}
    if path.is_dir():
        for n in want:
            p = path / n
            if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file():
                out[n] = p.read_bytes()
        return out
    with SafeZip(path, label=f"the zip archive {name or path.name}", error=JobInputError) as zf:
        for member in zf.names():
            base = Path(member).name
            if base in want and base not in out and Path(member).suffix.lower() in IMAGE_SUFFIXES:
                out[base] = zf.read(member)
    return out


def _decode_stills(items, src: MediaSource) -> Iterator[tuple[int, float | None, str, np.ndarray]]:
    """Decode each still (JPEG, PNG, ...) with the service's pixel limit; an image that is not one,
    or too large, is recorded in ``src.errors`` and skipped. A damaged archive stops the job."""
    index = 0
    limit = images.max_pixels_from_env()
    for name, read in items:
        try:
            img = images.decode_image(read(), cv2.IMREAD_COLOR, limit)
        except (OSError, images.ImageInputError) as exc:
            src.errors.append(f"{name}: {exc}")
            continue
        yield index, None, name, img
        index += 1


def _open_video(path: Path, name: str) -> MediaSource:
    try:
        container = av.open(str(path))
    except (av.error.FFmpegError, OSError, UnicodeDecodeError, ValueError):
        raise JobInputError(f"{name} is not a video or a zip of images that can be decoded") from None
    try:
        if not container.streams.video:
            raise JobInputError(f"{name} has no video stream")
        stream = container.streams.video[0]
        count = int(stream.frames or 0)
        if count <= 0 and stream.duration and stream.average_rate:
            count = int(float(stream.duration * stream.time_base) * float(stream.average_rate))
    finally:
        container.close()

    src = MediaSource("video", name, count or None, lambda: None)

    def frames():
        with av.open(str(path)) as cont:
            vs = cont.streams.video[0]
            vs.thread_type = "AUTO"
            index = 0
            try:
                for frame in cont.decode(vs):
                    t = float(frame.time) if frame.time is not None else None
                    yield index, t, f"frame_{index:06d}", frame.to_ndarray(format="bgr24")
                    index += 1
            except (av.error.FFmpegError, ValueError) as exc:
                # A damaged tail ends the video; the frames before it stay usable.
                src.errors.append(f"decoding stopped after frame {index}: {exc}")

    src._iter = frames
    return src


def sharpness(gray: np.ndarray) -> float:
    """Variance of the Laplacian of gray (H, W) uint8: low for blurred frames."""
    return float(cv2.Laplacian(gray, cv2.CV_64F).var())


@dataclass
class SelectionStats:
    """What frame selection did (for the report)."""

    decoded: int = 0
    selected: int = 0
    skipped_blurred: int = 0
    stride: int = 1
    truncated: bool = False
    native_size: tuple[int, int] | None = None
    working_size: tuple[int, int] | None = None
    scale: float = 1.0


def select_frames(
    source: MediaSource,
    intrinsics: Intrinsics,
    frame_step: int | None = None,
    min_motion: float = 0.004,
    blur_ratio: float = 0.5,
    max_frames: int | None = 400,
    max_width: int = 1280,
    stats: SelectionStats | None = None,
    on_decoded: Callable[[int], None] | None = None,
    on_skipped: Callable[[Skipped], None] | None = None,
) -> Iterator[Frame]:
    """Stream the frames worth tracking.

    ``frame_step`` k keeps every k-th decoded frame; None keeps a frame once the image moved
    ``min_motion`` of the width since the last kept one (phase correlation of thumbnails).
    A video frame whose sharpness is below ``blur_ratio`` times the median of the last 15 frames
    is skipped and the next sharp one taken instead (but never more than one step late).
    A video gives at most ``max_frames`` frames: the step grows when the length is known, else the
    stream is cut (stills: every photo, however many). Frames are resized to at most ``max_width`` and undistorted with ``intrinsics.dist``;
    ``intrinsics`` (native resolution) are checked against the first frame's size.
    ``on_decoded(n)`` is called after each decoded frame; ``on_skipped`` receives every decoded
    frame that is not selected (with its working-resolution gray image when it has the first
    frame's size), before the next selected frame is yielded.
    """
    stats = stats if stats is not None else SelectionStats()
    stride = 1
    if source.kind != "video":
        max_frames = None
    elif source.count:
        stride = max(1, math.ceil(source.count / (max_frames * (frame_step or 1))))
    stats.stride = stride
    recent: deque[float] = deque(maxlen=15)
    last_thumb = None
    since = 0
    maps = None
    scale = 1.0
    for index, time, name, bgr in source:
        stats.decoded += 1
        if on_decoded is not None:
            on_decoded(stats.decoded)
        if stats.native_size is None:
            h, w = bgr.shape[:2]
            stats.native_size = (w, h)
            intrinsics.check(w, h)
            scale = min(1.0, max_width / w)
            stats.scale = scale
            stats.working_size = (int(round(w * scale)), int(round(h * scale)))
            if intrinsics.dist is not None:
                k = intrinsics.scaled(scale).K
                maps = cv2.initUndistortRectifyMap(k, intrinsics.dist, None, k, stats.working_size, cv2.CV_16SC2)
        elif bgr.shape[1::-1] != stats.native_size:
            source.errors.append(f"{name}: size {bgr.shape[1]}x{bgr.shape[0]} differs from the first frame; skipped")
            if on_skipped is not None:
                on_skipped(Skipped(index, time, name, None, "size differs from the first frame"))
            continue

        def skip(reason: str) -> None:
            if on_skipped is not None:
                gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
                if scale != 1.0:
                    gray = cv2.resize(gray, stats.working_size, interpolation=cv2.INTER_AREA)
                if maps is not None:
                    gray = cv2.remap(gray, maps[0], maps[1], cv2.INTER_LINEAR)
                on_skipped(Skipped(index, time, name, gray, reason))

        if index % stride:
            skip(f"max_frames: every {stride}th frame tracked")
            continue
        since += 1
        thumb_s = _THUMB / max(bgr.shape[:2])
        thumb = cv2.cvtColor(cv2.resize(bgr, None, fx=thumb_s, fy=thumb_s, interpolation=cv2.INTER_AREA),
                             cv2.COLOR_BGR2GRAY)
        sharp = sharpness(thumb)
        # Stills are not redundant like video frames: a soft one is kept rather than lost.
        blurred = (source.kind == "video" and blur_ratio > 0 and len(recent) >= 5
                   and sharp < blur_ratio * float(np.median(recent)))
        recent.append(sharp)
        if last_thumb is None:
            due, late = True, True
        elif frame_step is not None:
            due, late = since >= frame_step, since >= 2 * frame_step
        else:
            shift, peak = global_shift(last_thumb, thumb, _THUMB)
            # A weak correlation peak means no single shift explains the change: large motion.
            motion = float(np.linalg.norm(shift)) / thumb.shape[1] if peak >= 0.05 else np.inf
            due, late = motion >= min_motion, motion >= 3 * min_motion and since >= 3
        if not due:
            skip(f"frame_step: every {frame_step}th frame tracked" if frame_step is not None
                 else "little motion since the last selected frame")
            continue
        if blurred and not late:
            stats.skipped_blurred += 1
            skip("blurred")
            continue
        if max_frames is not None and stats.selected >= max_frames:
            stats.truncated = True
            break
        image = bgr if scale == 1.0 else cv2.resize(bgr, stats.working_size, interpolation=cv2.INTER_AREA)
        if maps is not None:
            image = cv2.remap(image, maps[0], maps[1], cv2.INTER_LINEAR)
        last_thumb = thumb
        since = 0
        stats.selected += 1
        yield Frame(index, time, name, image, cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))


def load_frames(media: str | Path, intrinsics: Intrinsics, indices: set[int] | list[int], max_width: int,
                name: str | None = None) -> dict[int, np.ndarray]:
    """The frames ``indices`` (decoded-frame numbers, as :class:`Frame.index`) of ``media`` again, exactly as
    :func:`select_frames` gave them: (H, W, 3) uint8 BGR at the working resolution (at most ``max_width``
    wide), undistorted with ``intrinsics.dist``. Decodes the media once more and keeps only those frames."""
    want = set(int(i) for i in indices)
    out: dict[int, np.ndarray] = {}
    if not want:
        return out
    source = open_media(media, name)
    native = None
    size = None
    maps = None
    for index, _, _, bgr in source:
        if native is None:
            h, w = bgr.shape[:2]
            native = (w, h)
            scale = min(1.0, max_width / w)
            size = (int(round(w * scale)), int(round(h * scale)))
            if intrinsics.dist is not None:
                k = intrinsics.scaled(scale).K
                maps = cv2.initUndistortRectifyMap(k, intrinsics.dist, None, k, size, cv2.CV_16SC2)
        if index not in want or bgr.shape[1::-1] != native:
            continue
        image = bgr if size == native else cv2.resize(bgr, size, interpolation=cv2.INTER_AREA)
        if maps is not None:
            image = cv2.remap(image, maps[0], maps[1], cv2.INTER_LINEAR)
        out[index] = image
        if len(out) == len(want):
            break
    return out
