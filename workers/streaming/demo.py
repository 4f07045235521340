"""The first-run demo: the procedural studio (workers.synth) seen by a 10-camera arc rig, with a
short recording of a small sphere circling the object group."""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

import numpy as np

from workers.synth import Scene, Sphere, default_arc_rig, default_scene, render_views
from workers.sweep.rig import Rig

from .recording import ArchiveWriter, RecordingInfo

DEMO_NAME = "Demo: procedural studio"
DEMO_CAMERAS = 10
DEMO_SIZE = (320, 240)
ORBIT_RADIUS = 0.5


def demo_rig(cameras: int = DEMO_CAMERAS, size: tuple[int, int] = DEMO_SIZE) -> Rig:
    """``cameras`` cameras on a 90-degree arc around the studio's objects, images ``size`` = (w, h)."""
    return Rig(tuple(default_arc_rig(cameras, width=size[0], height=size[1])))


def demo_scene(phase: float) -> Scene:
    """The studio with its small sphere at ``phase`` (0..1) of a circle around the object group."""
    scene = default_scene()
    objects = list(scene.objects)
    k, ball = next((i, o) for i, o in enumerate(objects) if isinstance(o, Sphere) and o.radius < 0.2)
    a0 = np.arctan2(ball.center[1], ball.center[0])
    a = a0 + 2 * np.pi * phase
    objects[k] = dataclasses.replace(ball, center=(ORBIT_RADIUS * float(np.cos(a)), ORBIT_RADIUS * float(np.sin(a)),
                                                   ball.center[2]))
    return dataclasses.replace(scene, objects=tuple(objects))


def build_demo_recording(rig: Rig, out: str | Path, frames: int, fps: float,
                         progress: Callable[[float, str], None] | None = None) -> RecordingInfo:
    """Render ``frames`` frames of :func:`demo_scene` with every rig camera into a recording archive
    at ``out``; the backgrounds are the exact empty-studio views."""
    writer = ArchiveWriter(out, rig, fps)
    cams = list(rig.cameras)
    try:
        for f in range(frames):
            views = render_views(demo_scene(f / frames), cams, with_background=(f == 0))
            for c, view in enumerate(views):
                writer.add(c, view.image)
                if f == 0:
                    writer.set_background(c, view.background)
            if progress is not None:
                progress((f + 1) / frames, f"rendering demo frame {f + 1}/{frames}")
        return writer.finish("given")
    except BaseException:
        writer.abort()
        raise
