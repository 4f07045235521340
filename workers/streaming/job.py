"""Job entry points of the streaming service (see workers.registry):

- ``run_recording_import`` (kind ``streaming.recording``, :class:`RecordingImportParams`): inputs
  ``rig`` (our rig JSON), ``media-NNN`` (videos) or ``archive`` (zip of image folders), optional
  ``background-NNN``; result ``frames.zip`` (the recording archive).
- ``run_batch_render`` (kind ``streaming.render``, :class:`BatchRenderParams`): inputs ``rig`` and
  ``recording`` (an archive); results ``video.mp4`` (H.264) and ``depth.zip`` (16-bit PNGs + path.json).
- ``run_demo_recording`` (kind ``streaming.demo``, :class:`DemoParams`): input ``rig``; result ``frames.zip``.
"""
from __future__ import annotations

import json
from typing import Any

import numpy as np

from workers.common.jobctx import JobContext, JobInputError
from workers.registry import JobKind
from workers.settings import worker_settings
from workers.sweep.rig import Rig
from workers.sweep.rig_io import rig_from_dict

from .batch import render_path
from .demo import demo_recording
from .images import ImageError, decode_image
from .params import ARCHIVE_INPUT, BatchRenderParams, DemoParams, RecordingImportParams, background_input, media_input
from .recording import RecordingArchive, RecordingError, check_videos, import_image_zip, import_videos
from .store import ARCHIVE_NAME
from .video import VideoError, probe_video

DEFAULT_IMAGE_FPS = 25.0
_USER_ERRORS = (VideoError, ImageError)
"""The streaming library's message fragments (``camera X: the image ...``) that reach a job unprefixed: its input
errors (RecordingError, RigError, CameraError) are InputErrors, which fail the job by themselves."""


def _rig(ctx: JobContext) -> Rig:
    try:
        return rig_from_dict(json.loads(ctx.read_input("rig")))
    except ValueError as exc:  # JSON, RigError, CameraError
        raise JobInputError(f"the rig calibration is unusable: {exc}") from None


def _label(ctx: JobContext, name: str) -> str:
    return str(ctx.input_meta.get(name, {}).get("filename") or name)


def run_recording_import(ctx: JobContext) -> dict[str, Any]:
    p = RecordingImportParams.model_validate(ctx.params)
    rig = _rig(ctx)
    out = ctx.result_path(ARCHIVE_NAME)
    try:
        backgrounds = _backgrounds(ctx, p, rig)
        if p.source == "videos":
            names = [media_input(i) for i in range(len(p.cameras))]
            videos = [(_label(ctx, n), ctx.input_path(n)) for n in names]
            infos = [(label, probe_video(path)) for label, path in videos]
            frames, fps = check_videos(infos, p.cameras, rig, p.max_frames)
            info = import_videos(videos, p.cameras, rig, out, frames, fps, backgrounds, ctx.progress)
        else:
            info = import_image_zip(ctx.input_path(ARCHIVE_INPUT), rig, out, p.fps or DEFAULT_IMAGE_FPS, p.max_frames,
                                    backgrounds, ctx.progress)
    except _USER_ERRORS as exc:
        raise JobInputError(str(exc)) from None
    return info.summary()


def _backgrounds(ctx: JobContext, p: RecordingImportParams, rig: Rig) -> dict[int, np.ndarray] | None:
    if not p.backgrounds:
        return None
    if sorted(p.backgrounds) != list(range(len(rig))):
        raise RecordingError(f"give a background image for every camera ({len(rig)}) or none")
    out = {}
    for i, cam in enumerate(p.backgrounds):
        name = background_input(i)
        c = rig[cam]
        try:
            out[cam] = decode_image(ctx.read_input(name), (c.width, c.height))
        except ImageError as exc:
            raise RecordingError(f"background {_label(ctx, name)} (camera {c.name}) {exc}") from None
    return out


def run_batch_render(ctx: JobContext) -> dict[str, Any]:
    p = BatchRenderParams.model_validate(ctx.params)
    rig = _rig(ctx)
    try:
        archive = RecordingArchive(ctx.input_path("recording"))
    except (KeyError, FileNotFoundError):
        raise JobInputError(f"recording {p.recording_id} is no longer stored") from None
    try:
        if list(archive.info.cameras) != rig.names:
            raise RecordingError("the recording was made for other cameras than the rig's")
        return render_path(rig, archive, p, ctx.result_path("video.mp4"), ctx.result_path("depth.zip"), ctx.progress)
    except _USER_ERRORS as exc:
        raise JobInputError(str(exc)) from None
    finally:
        archive.close()


def run_demo_recording(ctx: JobContext) -> dict[str, Any]:
    p = DemoParams.model_validate(ctx.params)
    rig = _rig(ctx)
    info = demo_recording(rig, ctx.result_path(ARCHIVE_NAME), p.frames, p.fps, worker_settings().demo_cache_dir,
                          ctx.progress)
    return info.summary()


RECORDING_JOB = JobKind("streaming.recording", run_recording_import, RecordingImportParams)
RENDER_JOB = JobKind("streaming.render", run_batch_render, BatchRenderParams)
DEMO_JOB = JobKind("streaming.demo", run_demo_recording, DemoParams)
JOBS = (RECORDING_JOB, RENDER_JOB, DEMO_JOB)
