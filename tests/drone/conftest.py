"""Fixtures for the drone engine: a short synthetic flight video, rendered once per session."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from workers.synth.flight import encode_video, flight_cameras, render_flight, terrain_scene

W, H = 320, 240


@dataclass
class Flight:
    path: Path
    cameras: list
    frames: list[np.ndarray]

    @property
    def K(self) -> np.ndarray:
        return self.cameras[0].K

    @property
    def intrinsics(self) -> str:
        K = self.K
        return f"{K[0, 0]},{K[1, 1]},{K[0, 2]},{K[1, 2]}"


@pytest.fixture(scope="session")
def flight(tmp_path_factory) -> Flight:
    """36 frames, 320x240, over 30 m of a small town at 25 m altitude, slight shake, H.264."""
    cams = flight_cameras(36, length=30.0, altitude=25.0, sway=3.0, width=W, height=H, fov_deg=70,
                          shake_deg=0.2, seed=3)
    frames = render_flight(terrain_scene(3, extent=80.0, n_buildings=10, n_trees=12), cams)
    path = encode_video(frames, tmp_path_factory.mktemp("flight") / "flight.mp4", fps=25)
    return Flight(path, cams, frames)
