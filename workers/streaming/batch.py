"""Batch renders: a camera path over a recording's frames -> H.264 MP4 + a zip of depth PNGs."""
from __future__ import annotations

import json
import time
import zipfile
from pathlib import Path
from typing import Callable

import numpy as np

from workers.camera import Camera
from workers.common.images import encode_png
from workers.sweep.renderer import RenderOptions, SweepRenderer
from workers.sweep.rig import Rig

from .params import BatchRenderParams, Keyframe, Orbit
from .recording import RecordingArchive, RecordingError
from .video import H264Writer
from .viewpoint import OrbitFrame, orbit_frame, path_cameras

DEPTH_SCALE = 1000.0
"""Depth PNG levels per world unit (millimetres for a rig in metres); 0 = no surface."""


def frame_indices(p: BatchRenderParams, recording_frames: int) -> list[int]:
    """The recording frame shown at each output frame (the range spread over the output length)."""
    end = recording_frames - 1 if p.frame_end is None else p.frame_end
    if p.frame_start >= recording_frames or end >= recording_frames:
        raise RecordingError(f"frames {p.frame_start}..{end} are out of range: the recording has "
                             f"{recording_frames} frames (0..{recording_frames - 1})")
    n = p.frames or (end - p.frame_start + 1)
    if n == 1:
        return [p.frame_start]
    return [int(round(p.frame_start + k * (end - p.frame_start) / (n - 1))) for k in range(n)]


def camera_path(p: BatchRenderParams, frame: OrbitFrame, count: int) -> list[Camera]:
    """``count`` virtual cameras along the request's orbit or keyframes."""
    size = (p.width, p.height)
    if p.orbit is not None:
        o = p.orbit
        keys = [Keyframe(orbit=Orbit(azimuth=a, elevation=o.elevation, distance=o.distance, target=o.target), fov=o.fov)
                for a in (o.azimuth_from, o.azimuth_to)]
        return path_cameras(keys, None, frame, size, count)
    ats = [k.at for k in p.keyframes] if p.keyframes[0].at is not None else None
    return path_cameras(list(p.keyframes), ats, frame, size, count)


def depth_png(depth: np.ndarray) -> bytes:
    """16-bit PNG of a depth map (h, w) float32 (inf = none): round(depth * DEPTH_SCALE), 0 = none,
    clipped to 65535."""
    levels = np.where(np.isfinite(depth), np.clip(np.round(depth * DEPTH_SCALE), 1, 65535), 0)
    return encode_png(levels.astype(np.uint16))


def render_path(rig: Rig, archive: RecordingArchive, p: BatchRenderParams, video_path: Path, depth_zip: Path,
                progress: Callable[[float, str], None]) -> dict:
    """Render the request into ``video_path`` (MP4) and ``depth_zip``; return a summary."""
    indices = frame_indices(p, archive.info.frames)
    cams = camera_path(p, orbit_frame(rig), len(indices))
    options = RenderOptions(**p.render_fields(p.render_quality)[0])
    renderer = SweepRenderer(rig, archive.frame_set(indices[0]), backgrounds=archive.backgrounds())
    shown = indices[0]
    fps = p.fps or archive.info.fps
    render_s = 0.0
    with H264Writer(video_path, p.width, p.height, fps, p.crf) as video, \
            zipfile.ZipFile(depth_zip, "w", zipfile.ZIP_STORED) as depths:
        for k, (cam, index) in enumerate(zip(cams, indices)):
            if index != shown:
                renderer.set_frames(archive.frame_set(index))
                shown = index
            t0 = time.perf_counter()
            result = renderer.render(cam, options)
            render_s += time.perf_counter() - t0
            video.write(result.image)
            depths.writestr(f"depth/{k:06d}.png", depth_png(result.depth))
            progress((k + 1) / len(cams), f"frame {k + 1}/{len(cams)}")
        depths.writestr("path.json", json.dumps({
            "depth_scale": DEPTH_SCALE, "frames": indices, "cameras": [c.to_dict() for c in cams]}))
    return {"frames": len(cams), "fps": fps, "width": p.width, "height": p.height,
            "recording_frames": [indices[0], indices[-1]], "depth_scale": DEPTH_SCALE,
            "mean_render_ms": round(render_s / len(cams) * 1e3, 2)}
