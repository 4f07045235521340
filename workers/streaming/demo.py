"""The first-run demo: the photographic studio (:func:`workers.synth.studio_scene`: a lit plank stage in
a green-screen studio, objects wrapped in photographs, soft shadows) seen by a 10-camera 640x480 arc rig, with a
short recording of a small ball circling the object group."""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

import numpy as np

from workers.synth import Scene, Sphere, default_arc_rig, render_moved, render_views, studio_scene
from workers.sweep.rig import Rig

from .recording import ArchiveWriter, RecordingInfo

DEMO_NAME = "Demo: photographic studio"
DEMO_CAMERAS = 10
DEMO_SIZE = (640, 480)
ORBIT_RADIUS = 0.5


def demo_rig(cameras: int = DEMO_CAMERAS, size: tuple[int, int] = DEMO_SIZE) -> Rig:
    """``cameras`` cameras on a 90-degree arc around the studio's objects, images ``size`` = (w, h)."""
    return Rig(tuple(default_arc_rig(cameras, width=size[0], height=size[1])))


def demo_scene(phase: float) -> Scene:
    """The studio with its small ball at ``phase`` (0..1) of a circle around the object group."""
    scene = studio_scene()
    objects = list(scene.objects)
    k, ball = _ball(scene)
    a0 = np.arctan2(ball.center[1], ball.center[0])
    a = a0 + 2 * np.pi * phase
    objects[k] = dataclasses.replace(ball, center=(ORBIT_RADIUS * float(np.cos(a)), ORBIT_RADIUS * float(np.sin(a)),
                                                   ball.center[2]))
    return dataclasses.replace(scene, objects=tuple(objects))


def _ball(scene: Scene) -> tuple[int, Sphere]:
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
        k, _ = _ball(first)
        stills = render_views(dataclasses.replace(first, objects=first.objects[:k] + first.objects[k + 1:]), cams)
        for c, still in enumerate(stills):
            writer.set_background(c, still.background)
        for f in range(frames):
            scene = demo_scene(f / frames)
            ball = _ball(scene)[1]
            for c, still in enumerate(stills):
                writer.add(c, render_moved(scene, still, ball))
            if progress is not None:
                progress((f + 1) / frames, f"rendering demo frame {f + 1}/{frames}")
        return writer.finish("given")
    except BaseException:
        writer.abort()
        raise
