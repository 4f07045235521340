"""Small procedural captures for the streaming tests: the demo studio seen by a few tiny cameras."""
from __future__ import annotations

import io
import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from workers.streaming.demo import demo_rig, demo_scene
from workers.streaming.framing import pack_message
from workers.streaming.video import H264Writer
from workers.sweep.rig import Rig
from workers.sweep.rig_io import rig_to_dict
from workers.synth import render_views

CAMERAS = 4
SIZE = (96, 72)
FRAMES = 3


@dataclass(frozen=True)
class Take:
    """frames[f][c]: frame f of camera c (H, W, 3) uint8; backgrounds[c] the empty studio;
    silhouettes[f][c] the true foreground masks."""

    rig: Rig
    frames: list[list[np.ndarray]]
    backgrounds: list[np.ndarray]
    silhouettes: list[list[np.ndarray]]


def make_take(cameras: int = CAMERAS, size: tuple[int, int] = SIZE, frames: int = FRAMES) -> Take:
    rig = demo_rig(cameras, size)
    views = [render_views(demo_scene(f / frames), list(rig.cameras), with_background=(f == 0)) for f in range(frames)]
    return Take(rig, [[v.image for v in vs] for vs in views], [v.background for v in views[0]],
                [[v.silhouette for v in vs] for vs in views])


def rig_json(rig: Rig) -> bytes:
    return json.dumps(rig_to_dict(rig)).encode()


def png(image: np.ndarray) -> bytes:
    return cv2.imencode(".png", image)[1].tobytes()


def jpeg(image: np.ndarray, quality: int = 95) -> bytes:
    return cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])[1].tobytes()


def zip_bytes(take: Take, wrapper: str | None = "take", backgrounds: bool = True, frames: list[int] | None = None) -> bytes:
    """A zip of per-camera image folders (``frames[c]`` images for camera c when given)."""
    buf = io.BytesIO()
    root = f"{wrapper}/" if wrapper else ""
    with zipfile.ZipFile(buf, "w") as zf:
        for c, cam in enumerate(take.rig.cameras):
            count = frames[c] if frames is not None else len(take.frames)
            for f in range(count):
                zf.writestr(f"{root}{cam.name}/frame{f + 1}.png", png(take.frames[f][c]))
            if backgrounds:
                zf.writestr(f"{root}backgrounds/{cam.name}.png", png(take.backgrounds[c]))
    return buf.getvalue()


def write_videos(take: Take, folder: Path, fps: float = 10.0, frames: list[int] | None = None,
                 names: list[str] | None = None) -> list[Path]:
    """One H.264 file per camera (``frames[c]`` frames when given), named after the cameras."""
    paths = []
    for c, cam in enumerate(take.rig.cameras):
        path = folder / f"{(names or take.rig.names)[c]}.mp4"
        count = frames[c] if frames is not None else len(take.frames)
        with H264Writer(path, cam.width, cam.height, fps, crf=12) as w:
            for f in range(count):
                w.write(take.frames[f % len(take.frames)][c])
        paths.append(path)
    return paths


def frame_set(images: list[bytes], **header: object) -> bytes:
    """A live frame-set message of encoded images (rig order unless ``cameras`` is given)."""
    return pack_message({"sizes": [len(i) for i in images], **header}, images)
