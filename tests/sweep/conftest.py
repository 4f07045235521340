"""A small procedural capture shared by the sweep tests: 6 cameras, 160x120, on a 75-degree arc."""
from __future__ import annotations

import numpy as np
import pytest

from workers.synth import arc_angles, arc_camera, default_arc_rig, default_scene, render_views
from workers.sweep.rig import Rig

SIZE = (160, 120)
NEAR, FAR = 1.6, 3.6


@pytest.fixture(scope="session")
def capture():
    """(scene, rig, views): views[i].image/background/silhouette/depth for rig camera i."""
    scene = default_scene()
    cams = default_arc_rig(6, arc_deg=75.0, width=SIZE[0], height=SIZE[1])
    views = render_views(scene, cams)
    return scene, Rig(tuple(cams)), views


@pytest.fixture(scope="session")
def between_camera():
    """A virtual camera on the arc halfway between rig cameras 2 and 3."""
    a = arc_angles(6, 75.0)
    return arc_camera(float((a[2] + a[3]) / 2), width=SIZE[0], height=SIZE[1], name="virtual")


def plane_step_at(depth: float, planes: int) -> float:
    """Spacing (m) of planes uniform in inverse depth between NEAR and FAR, near ``depth``."""
    ds = (1 / NEAR - 1 / FAR) / (planes - 1)
    return float(depth**2 * ds)


__all__ = ["FAR", "NEAR", "SIZE", "plane_step_at", "np"]
