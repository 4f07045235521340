"""Recordings: synchronised frames of every rig camera, checked against the rig and stored as one
archive with random access by frame index.

Sources: one video per camera (synchronised by frame index), or a zip of per-camera image folders
(``<camera name>/<frames in name order>``, optional ``backgrounds/<camera name>.<ext>``). Every
camera must have the same number of frames, at its calibrated size; videos must share one rate.

The archive (``frames.zip``, stored uncompressed, PNG members, lossless)::

    recording.json              {"version", "frames", "fps", "cameras", "sizes", "background"}
    frames/<cam>/<frame>.png    cam = rig index (3 digits), frame = index (6 digits)
    backgrounds/<cam>.png       the empty-scene model of each camera

The background is the given empty-scene image per camera, or else the per-pixel temporal median of
up to 15 frames spread over the recording (right when the subject moves; give backgrounds when
parts of it stand still).
"""
from __future__ import annotations

import json
import re
import threading
import zipfile
from dataclasses import asdict, dataclass
from pathlib import Path, PurePosixPath
from typing import BinaryIO, Callable, Iterable, Literal, Sequence

import numpy as np

from workers.common.errors import InputError
from workers.common.images import encode_png
from workers.common.safezip import SafeZip, ZipLimits
from workers.sweep.rig import Rig
from workers.sweep.rig_io import IMAGE_EXTENSIONS

from .images import ImageError, decode_image, image_size
from .video import VideoError, VideoInfo, decode_frames, probe_video

ARCHIVE_VERSION = 1
INFO_MEMBER = "recording.json"
BACKGROUND_FOLDER = "backgrounds"
MEDIAN_SAMPLES = 15
RATE_TOLERANCE = 0.01
Progress = Callable[[float, str], None]


class RecordingError(InputError):
    """Media that do not make a recording of the rig; the message names the file and camera."""

    code = "invalid_recording"


@dataclass(frozen=True)
class RecordingInfo:
    """A stored recording: ``frames`` per camera at ``fps``; ``cameras`` names and ``sizes``
    (width, height) in rig order; ``background`` "given" or "median"."""

    frames: int
    fps: float
    cameras: tuple[str, ...]
    sizes: tuple[tuple[int, int], ...]
    background: Literal["given", "median"]

    def to_dict(self) -> dict:
        return {"version": ARCHIVE_VERSION, **asdict(self)}

    def summary(self) -> dict:
        """The result summary of the job that made the recording (an import or the demo)."""
        return {"frames": self.frames, "fps": self.fps, "cameras": len(self.cameras), "background": self.background}

    @classmethod
    def from_dict(cls, d: dict) -> "RecordingInfo":
        return cls(int(d["frames"]), float(d["fps"]), tuple(d["cameras"]),
                   tuple((int(w), int(h)) for w, h in d["sizes"]), d["background"])


def frame_member(cam: int, frame: int) -> str:
    return f"frames/{cam:03d}/{frame:06d}.png"


def background_member(cam: int) -> str:
    return f"{BACKGROUND_FOLDER}/{cam:03d}.png"


# --- matching uploads to cameras ------------------------------------------------------------------
def match_cameras(labels: Sequence[str], rig: Rig, what: str = "videos") -> list[int]:
    """Rig camera index of each upload: by file stem (camera name, or the stem of its image file),
    else by upload order when there is one per camera. RecordingError otherwise."""
    stems = {}
    for i, (cam, image) in enumerate(zip(rig.names, rig.image_files)):
        stems.setdefault(cam, i)
        stems.setdefault(PurePosixPath(image).stem, i)
    by_name = [stems.get(PurePosixPath(label).stem) for label in labels]
    if all(i is not None for i in by_name) and len(set(by_name)) == len(by_name):
        return [int(i) for i in by_name]  # type: ignore[arg-type]
    if len(labels) == len(rig):
        return list(range(len(rig)))
    raise RecordingError(f"got {len(labels)} {what} for {len(rig)} cameras; name each after its camera "
                         f"({', '.join(rig.names)}) or send one per camera in rig order")


def _require_all(cameras: Sequence[int], rig: Rig, what: str) -> None:
    missing = sorted(set(range(len(rig))) - set(cameras))
    if missing or len(cameras) != len(rig):
        names = ", ".join(rig.names[i] for i in missing) or "none"
        raise RecordingError(f"need one {what} per rig camera ({len(rig)}), got {len(cameras)}; missing: {names}")


def check_videos(infos: Sequence[tuple[str, VideoInfo]], cameras: Sequence[int], rig: Rig,
                 max_frames: int) -> tuple[int, float]:
    """(frames, fps) of videos that make a recording of ``rig``: one per camera, each at its
    camera's calibrated size, all with the same frame count (at most ``max_frames``) and rate."""
    _require_all(cameras, rig, "video")
    for (label, info), c in zip(infos, cameras):
        cam = rig[c]
        if (info.width, info.height) != (cam.width, cam.height):
            raise RecordingError(f"{label} (camera {cam.name}) is {info.width}x{info.height}; "
                                 f"the calibration says {cam.width}x{cam.height}")
        if info.frames < 1:
            raise RecordingError(f"{label} (camera {cam.name}) has no frames")
    counts = {label: info.frames for label, info in infos}
    if len(set(counts.values())) > 1:
        listing = ", ".join(f"{k}: {v}" for k, v in counts.items())
        raise RecordingError(f"the videos differ in length ({listing} frames); they must be synchronised frame by frame")
    frames = next(iter(counts.values()))
    if frames > max_frames:
        raise RecordingError(f"the videos have {frames} frames; the limit is {max_frames}")
    rates = [info.fps for _, info in infos]
    if not all(r > 0 for r in rates):
        raise RecordingError("a video does not state its frame rate")
    if max(rates) > min(rates) * (1 + RATE_TOLERANCE):
        listing = ", ".join(f"{label}: {info.fps:g}" for label, info in infos)
        raise RecordingError(f"the videos' frame rates differ ({listing} fps)")
    return frames, float(np.median(rates))


# --- image folders in a zip -----------------------------------------------------------------------
@dataclass(frozen=True)
class ImageFolders:
    """Members of a zip of per-camera image folders: ``frames[c]`` the frame members of rig camera
    c in order; ``backgrounds[c]`` its empty-scene image member or None."""

    frames: list[list[str]]
    backgrounds: list[str | None]


def _natural_key(name: str) -> list:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def scan_image_zip(zf: zipfile.ZipFile, rig: Rig, max_frames: int) -> ImageFolders:
    """Map a zip's folders to rig cameras (by folder name) and check the frame counts; image sizes
    are checked from the first image of each camera (:func:`check_image_sizes`)."""
    entries = [(PurePosixPath(i.filename), i.filename) for i in zf.infolist() if not i.is_dir()]
    entries = [(p, n) for p, n in entries if not any(part.startswith((".", "__MACOSX")) for part in p.parts)
               and p.suffix.lower() in IMAGE_EXTENSIONS]
    if not entries:
        raise RecordingError("the zip holds no images (expected <camera name>/<frame image> folders)")
    tops = {p.parts[0] for p, _ in entries}
    if len(tops) == 1 and all(len(p.parts) >= 3 for p, _ in entries) and tops.isdisjoint(rig.names):
        entries = [(PurePosixPath(*p.parts[1:]), n) for p, n in entries]  # one wrapping folder
    index = {name: i for i, name in enumerate(rig.names)}
    frames: list[list[str]] = [[] for _ in rig.names]
    backgrounds: list[str | None] = [None] * len(rig)
    for path, member in entries:
        folder = path.parts[0] if len(path.parts) == 2 else ""
        if folder in index:
            frames[index[folder]].append(member)
        elif folder == BACKGROUND_FOLDER and path.stem in index:
            backgrounds[index[path.stem]] = member
        else:
            raise RecordingError(f"{member}: folder {folder or '(none)'!r} is not a rig camera "
                                 f"({', '.join(rig.names)}) nor {BACKGROUND_FOLDER}/<camera>")
    for c, names in enumerate(frames):
        names.sort(key=_natural_key)
    counts = {rig.names[c]: len(f) for c, f in enumerate(frames)}
    if min(counts.values()) == 0:
        empty = ", ".join(k for k, v in counts.items() if v == 0)
        raise RecordingError(f"no images for camera(s) {empty}")
    if len(set(counts.values())) > 1:
        listing = ", ".join(f"{k}: {v}" for k, v in counts.items())
        raise RecordingError(f"the camera folders differ in length ({listing} images); they must be synchronised")
    if len(frames[0]) > max_frames:
        raise RecordingError(f"the folders hold {len(frames[0])} frames; the limit is {max_frames}")
    if any(b is not None for b in backgrounds) and any(b is None for b in backgrounds):
        missing = ", ".join(rig.names[c] for c, b in enumerate(backgrounds) if b is None)
        raise RecordingError(f"give a background image for every camera or none; missing: {missing}")
    return ImageFolders(frames, backgrounds)


def check_image_sizes(zf: zipfile.ZipFile, folders: ImageFolders, rig: Rig) -> None:
    """Each camera's first image and background are at the calibrated size (read from the headers)."""
    for c, cam in enumerate(rig.cameras):
        for member in (folders.frames[c][0], folders.backgrounds[c]):
            if member is None:
                continue
            with zf.open(member) as f:
                size = image_size(f.read(1 << 16))
            if size is None:
                raise RecordingError(f"{member}: not a JPEG or PNG whose size can be read")
            if size != (cam.width, cam.height):
                raise RecordingError(f"{member} is {size[0]}x{size[1]}; camera {cam.name} is calibrated "
                                     f"at {cam.width}x{cam.height}")


# --- writing and reading archives -----------------------------------------------------------------
class ArchiveWriter:
    """Builds a recording archive frame by frame (nothing but the current frame held in memory)."""

    def __init__(self, path: str | Path, rig: Rig, fps: float) -> None:
        self.rig = rig
        self.fps = float(fps)
        self._zip = zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED, allowZip64=True)
        self._counts = [0] * len(rig)
        self._backgrounds = [False] * len(rig)

    def add(self, cam: int, image: np.ndarray) -> None:
        """Append the next frame (H, W, 3) uint8 BGR of rig camera ``cam``."""
        self._check(cam, image)
        self._zip.writestr(frame_member(cam, self._counts[cam]), encode_png(image))
        self._counts[cam] += 1

    def set_background(self, cam: int, image: np.ndarray) -> None:
        """The empty-scene image (H, W, 3) uint8 BGR of rig camera ``cam``."""
        self._check(cam, image)
        self._zip.writestr(background_member(cam), encode_png(image))
        self._backgrounds[cam] = True

    def finish(self, background: Literal["given", "median"]) -> RecordingInfo:
        """Write the index; every camera must have the same number of frames and a background."""
        if len(set(self._counts)) != 1 or self._counts[0] == 0:
            listing = ", ".join(f"{n}: {k}" for n, k in zip(self.rig.names, self._counts))
            raise RecordingError(f"the cameras differ in length ({listing} frames); they must be synchronised")
        if not all(self._backgrounds):
            raise RecordingError("a camera has no background")
        info = RecordingInfo(self._counts[0], self.fps, tuple(self.rig.names),
                             tuple((c.width, c.height) for c in self.rig.cameras), background)
        self._zip.writestr(INFO_MEMBER, json.dumps(info.to_dict()))
        self._zip.close()
        return info

    def abort(self) -> None:
        self._zip.close()

    def _check(self, cam: int, image: np.ndarray) -> None:
        c = self.rig[cam]
        if image.shape != (c.height, c.width, 3) or image.dtype != np.uint8:
            raise RecordingError(f"camera {c.name}: a frame is {image.shape} {image.dtype}; "
                                 f"the calibration says ({c.height}, {c.width}, 3) uint8")


class RecordingArchive:
    """Random access to a stored recording: ``info``, ``frame_set(i)``, ``backgrounds()``.

    ``source`` is a path or a seekable binary file (closed with the archive). Thread-safe."""

    def __init__(self, source: str | Path | BinaryIO) -> None:
        try:
            self._zip = zipfile.ZipFile(source)
            self.info = RecordingInfo.from_dict(json.loads(self._zip.read(INFO_MEMBER)))
        except (zipfile.BadZipFile, KeyError, ValueError) as exc:
            raise RecordingError(f"not a recording archive ({exc})") from None
        self._lock = threading.Lock()

    def _image(self, member: str, cam: int) -> np.ndarray:
        with self._lock:
            data = self._zip.read(member)
        return decode_image(data, self.info.sizes[cam])

    def frame_set(self, index: int) -> list[np.ndarray]:
        """Frame ``index`` of every camera, rig order, each (H, W, 3) uint8 BGR."""
        if not 0 <= index < self.info.frames:
            raise IndexError(f"frame {index} is out of range: the recording has {self.info.frames} frames")
        return [self._image(frame_member(c, index), c) for c in range(len(self.info.cameras))]

    def backgrounds(self) -> list[np.ndarray]:
        """The empty-scene model of every camera, rig order, (H, W, 3) uint8 BGR."""
        return [self._image(background_member(c), c) for c in range(len(self.info.cameras))]

    def close(self) -> None:
        self._zip.close()


# --- importing ------------------------------------------------------------------------------------
def median_sample_indices(frames: int, samples: int = MEDIAN_SAMPLES) -> set[int]:
    """Frame indices (at most ``samples``, spread evenly) used for a temporal-median background."""
    return set(np.linspace(0, frames - 1, min(frames, samples)).round().astype(int).tolist())


def temporal_median(images: Iterable[np.ndarray]) -> np.ndarray:
    """Per-pixel median of images (H, W, 3) uint8 -> (H, W, 3) uint8."""
    return np.median(np.stack(list(images)), axis=0).round().astype(np.uint8)


def import_videos(videos: Sequence[tuple[str, str | Path]], cameras: Sequence[int], rig: Rig, out: str | Path,
                  frames: int, fps: float, backgrounds: dict[int, np.ndarray] | None = None,
                  progress: Progress | None = None) -> RecordingInfo:
    """Decode one video per camera into an archive at ``out``.

    videos: (label, path) per upload; cameras: rig index of each; frames/fps: what the probe found
    (:func:`check_videos`); a video decoding to another count is refused. backgrounds: rig index ->
    empty-scene image (all cameras) or None for temporal medians."""
    _require_all(cameras, rig, "video")
    writer = ArchiveWriter(out, rig, fps)
    samples = median_sample_indices(frames)
    try:
        for k, ((label, path), cam) in enumerate(zip(videos, cameras)):
            kept = []
            count = 0
            try:
                for image in decode_frames(path):
                    if count >= frames:
                        raise RecordingError(f"{label} decodes to more than {frames} frames; the videos differ in length")
                    writer.add(cam, _sized(image, rig, cam, label))
                    if count in samples:
                        kept.append(image)
                    count += 1
                    if progress is not None and (count % 4 == 0 or count == frames):
                        progress((k + count / frames) / len(videos), f"decoding {label}: frame {count}/{frames}")
            except VideoError as exc:
                raise RecordingError(f"{label} {exc}") from None
            if count != frames:
                raise RecordingError(f"{label} decodes to {count} frames, not {frames}; the videos differ in length")
            bg = backgrounds.get(cam) if backgrounds else None
            writer.set_background(cam, bg if bg is not None else temporal_median(kept))
        return writer.finish("given" if backgrounds else "median")
    except BaseException:
        writer.abort()
        raise


def import_image_zip(archive: str | Path, rig: Rig, out: str | Path, fps: float, max_frames: int,
                     backgrounds: dict[int, np.ndarray] | None = None, progress: Progress | None = None) -> RecordingInfo:
    """Decode a zip of per-camera image folders (see the module docstring) into an archive at ``out``.

    backgrounds: rig index -> empty-scene image, overriding those in the zip (None: the zip's, or
    temporal medians)."""
    with SafeZip(archive, label="the archive", error=RecordingError) as safe:
        zf = safe.zipfile
        folders = scan_image_zip(zf, rig, max_frames)
        check_image_sizes(zf, folders, rig)
        frames = len(folders.frames[0])
        samples = median_sample_indices(frames)
        given = dict(backgrounds or {})
        if not given and folders.backgrounds[0] is not None:
            given = {c: _zip_image(safe, m, rig, c) for c, m in enumerate(folders.backgrounds) if m is not None}
        writer = ArchiveWriter(out, rig, fps)
        try:
            total = frames * len(rig)
            for c in range(len(rig)):
                kept = []
                for f, member in enumerate(folders.frames[c]):
                    image = _zip_image(safe, member, rig, c)
                    writer.add(c, image)
                    if f in samples:
                        kept.append(image)
                    done = c * frames + f + 1
                    if progress is not None and (done % 4 == 0 or done == total):
                        progress(done / total, f"decoding {rig.names[c]}: image {f + 1}/{frames}")
                writer.set_background(c, given[c] if given else temporal_median(kept))
            return writer.finish("given" if given else "median")
        except BaseException:
            writer.abort()
            raise


def _zip_image(zf: SafeZip, member: str, rig: Rig, cam: int) -> np.ndarray:
    c = rig[cam]
    try:
        return decode_image(zf.read(member), (c.width, c.height))
    except ImageError as exc:
        raise RecordingError(f"{member} (camera {c.name}) {exc}") from None


def _sized(image: np.ndarray, rig: Rig, cam: int, label: str) -> np.ndarray:
    c = rig[cam]
    if image.shape[:2] != (c.height, c.width):
        raise RecordingError(f"{label}: a frame is {image.shape[1]}x{image.shape[0]}; "
                             f"camera {c.name} is calibrated at {c.width}x{c.height}")
    return image


# --- uploads, checked before a job is made of them --------------------------------------------------
def check_video_uploads(videos: Sequence[tuple[str, BinaryIO]], cameras: Sequence[int], rig: Rig,
                        max_frames: int) -> None:
    """Probe each uploaded (name, file) video and check them against ``rig`` (:func:`check_videos`);
    RecordingError naming the file. Each file is left at its start."""
    infos = []
    for name, file in videos:
        try:
            infos.append((name, probe_video(file)))
        except VideoError as exc:
            raise RecordingError(f"{name} {exc}") from None
        finally:
            file.seek(0)
    check_videos(infos, cameras, rig, max_frames)


def check_archive_upload(archive: BinaryIO, name: str, rig: Rig, max_frames: int, limits: ZipLimits) -> None:
    """Check an uploaded zip's structure (SafeZip: member count, sizes, ratio, names) and its layout and
    image sizes against ``rig``; RecordingError. The file is left at its start."""
    try:
        with SafeZip(archive, limits, name, RecordingError) as zf:
            check_image_sizes(zf.zipfile, scan_image_zip(zf.zipfile, rig, max_frames), rig)
    finally:
        archive.seek(0)


def check_background_uploads(backgrounds: Sequence[tuple[str, BinaryIO]], cameras: Sequence[int], rig: Rig) -> None:
    """One background image per camera of ``rig`` (``cameras[i]`` for upload ``i``), each of its camera's size
    (read from the header); RecordingError otherwise. Each file is left at its start."""
    if sorted(cameras) != list(range(len(rig))):
        raise RecordingError(f"give one background image per camera ({len(rig)}) or none")
    for (name, file), c in zip(backgrounds, cameras):
        size = image_size(file.read(1 << 16))
        file.seek(0)
        cam = rig[c]
        if size != (cam.width, cam.height):
            found = "not a JPEG or PNG" if size is None else f"{size[0]}x{size[1]}"
            raise RecordingError(f"background {name} (camera {cam.name}) is {found}; "
                                 f"the calibration says {cam.width}x{cam.height}")
