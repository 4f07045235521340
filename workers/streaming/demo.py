"""The first-run demo: the photographic studio (:func:`workers.synth.studio_scene`: a lit plank stage in
a green-screen studio, objects wrapped in photographs, soft shadows) seen by a 10-camera 640x480 arc rig, with a
short recording of a small ball circling the object group.

The recording is the same for the same rig, length and renderer, and takes about 20 s of two cores to
render: :func:`demo_recording` keeps one rendered copy in a cache folder (``sweepcast warmup`` fills it
before the first start, the demo job on the first start otherwise) and copies it from there. A wheel built by
``make wheel`` carries one too (:data:`SHIPPED_DEMO`), read-only: used when the cache folder has none.
"""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import shutil
import uuid
from pathlib import Path
from typing import Callable

import numpy as np

from workers.portable_cache import SHIPPED_DEMO
from workers.synth import Scene, Sphere, default_arc_rig, render_moved, render_views, studio_scene
from workers.sweep.rig import Rig
from workers.sweep.rig_io import rig_to_dict

from .recording import ArchiveWriter, RecordingArchive, RecordingError, RecordingInfo

log = logging.getLogger("sweepcast.demo")

DEMO_NAME = "Demo: photographic studio"
DEMO_CAMERAS = 10
DEMO_SIZE = (640, 480)
ORBIT_RADIUS = 0.5
_WORKERS = Path(__file__).resolve().parents[1]
RENDERER_SOURCES = (*sorted((_WORKERS / "synth").glob("*.py")), Path(__file__).resolve(),
                    _WORKERS / "streaming" / "recording.py", _WORKERS / "common" / "images.py")
"""The files whose code decides the recording's pixels and archive: a change to any of them renders it anew."""


def demo_rig(cameras: int = DEMO_CAMERAS, size: tuple[int, int] = DEMO_SIZE) -> Rig:
    """``cameras`` cameras on a 90-degree arc around the studio's objects, images ``size`` = (w, h)."""
    return Rig(tuple(default_arc_rig(cameras, width=size[0], height=size[1])))


def demo_scene(phase: float) -> Scene:
    """The studio with its small ball at ``phase`` (0..1) of a circle around the object group."""
    scene = studio_scene()
    objects = list(scene.objects)
    k, ball = demo_ball(scene)
    a0 = np.arctan2(ball.center[1], ball.center[0])
    a = a0 + 2 * np.pi * phase
    objects[k] = dataclasses.replace(ball, center=(ORBIT_RADIUS * float(np.cos(a)), ORBIT_RADIUS * float(np.sin(a)),
                                                   ball.center[2]))
    return dataclasses.replace(scene, objects=tuple(objects))


def demo_ball(scene: Scene) -> tuple[int, Sphere]:
    """Index and object of the studio's small (moving) ball."""
    return next((i, o) for i, o in enumerate(scene.objects) if isinstance(o, Sphere) and o.radius < 0.2)


def build_demo_recording(rig: Rig, out: str | Path, frames: int, fps: float,
                         progress: Callable[[float, str], None] | None = None) -> RecordingInfo:
    """Render ``frames`` frames of :func:`demo_scene` with every rig camera into a recording archive
    at ``out``; the backgrounds are the exact empty-studio views. Each camera's view of the studio
    without the ball is cast once; each frame then casts again only the rays the ball can change (it
    or its shadow: :func:`workers.synth.render_moved`, the same pixels as a full render)."""
    writer = ArchiveWriter(out, rig, fps)
    cams = list(rig.cameras)
    try:
        first = demo_scene(0.0)
        k, _ = demo_ball(first)
        stills = render_views(dataclasses.replace(first, objects=first.objects[:k] + first.objects[k + 1:]), cams)
        for c, still in enumerate(stills):
            writer.set_background(c, still.background)
        for f in range(frames):
            scene = demo_scene(f / frames)
            ball = demo_ball(scene)[1]
            for c, still in enumerate(stills):
                writer.add(c, render_moved(scene, still, ball))
            if progress is not None:
                progress((f + 1) / frames, f"rendering demo frame {f + 1}/{frames}")
        return writer.finish("given")
    except BaseException:
        writer.abort()
        raise


def demo_recording_key(rig: Rig, frames: int, fps: float) -> str:
    """Hex SHA-256 of everything the demo recording is made of: the rig's calibration, ``frames``, ``fps``
    and the source of :data:`RENDERER_SOURCES` (the cache's key)."""
    h = hashlib.sha256(json.dumps([rig_to_dict(rig), frames, float(fps)], sort_keys=True).encode())
    for source in RENDERER_SOURCES:
        h.update(source.read_bytes())
    return h.hexdigest()


def _cache_file(cache_dir: Path, rig: Rig, frames: int, fps: float) -> Path:
    return Path(cache_dir) / f"{demo_recording_key(rig, frames, fps)}.zip"


def _read_kept(cached: Path, rig: Rig, frames: int) -> RecordingInfo | None:
    """The info of the kept recording ``cached`` when it is readable as a recording of ``rig`` with ``frames``."""
    try:
        archive = RecordingArchive(cached)
    except (OSError, RecordingError):
        return None
    archive.close()
    if archive.info.frames == frames and archive.info.cameras == tuple(rig.names):
        return archive.info
    log.warning("the cached demo recording %s does not match its key; it will be rendered anew", cached)
    return None


def cached_demo_recording(cache_dir: Path | None, rig: Rig, frames: int, fps: float
                          ) -> tuple[Path, RecordingInfo] | None:
    """The kept recording of ``rig`` (``frames`` at ``fps``) in ``cache_dir`` (None: none), else the one a wheel
    carries (:data:`SHIPPED_DEMO`), and its info, when it is there and readable as a recording of that length and
    rig; else None."""
    for folder in ([] if cache_dir is None else [cache_dir]) + [SHIPPED_DEMO]:
        cached = _cache_file(folder, rig, frames, fps)
        info = _read_kept(cached, rig, frames) if cached.exists() else None
        if info is not None:
            return cached, info
    return None


def demo_recording(rig: Rig, out: str | Path, frames: int, fps: float, cache_dir: Path | None,
                   progress: Callable[[float, str], None] | None = None) -> RecordingInfo:
    """:func:`build_demo_recording` into ``out``, by way of ``cache_dir`` (None: no cache): a copy of the
    cached recording of the same :func:`demo_recording_key` when there is one; else rendered, and then
    kept there as the folder's only recording. The cache is only ever a shortcut: an unreadable or
    unwritable one is logged and the recording rendered."""
    kept = cached_demo_recording(cache_dir, rig, frames, fps)
    if kept is not None:
        cached, info = kept
        try:
            shutil.copyfile(cached, out)
            if progress is not None:
                progress(1.0, "demo recording copied from the cache")
            return info
        except OSError as exc:
            log.warning("the cached demo recording %s could not be copied (%s); rendering it", cached, exc)
    info = build_demo_recording(rig, out, frames, fps, progress)
    if cache_dir is not None:
        _keep(Path(out), _cache_file(cache_dir, rig, frames, fps))
    return info


def _keep(recording: Path, cached: Path) -> None:
    """Copy ``recording`` to ``cached`` atomically (a reader never sees half of it) and delete the folder's
    other recordings (those of an earlier renderer or rig)."""
    part = cached.with_name(f"{cached.name}.{uuid.uuid4().hex}.part")
    try:
        cached.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(recording, part)
        os.replace(part, cached)
        for old in cached.parent.glob("*.zip"):
            if old != cached:
                old.unlink(missing_ok=True)
    except OSError as exc:
        log.warning("could not keep the demo recording in %s: %s", cached.parent, exc)
    finally:
        with contextlib.suppress(OSError):
            part.unlink(missing_ok=True)
