"""Fixtures for the drone engine: a short synthetic flight video (rendered once per session) and a
fake job context over a temporary folder."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

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


@dataclass
class FakeContext:
    """A JobContext over a temporary folder (inputs in ``in/``, results in ``out/``)."""

    root: Path
    params: dict[str, Any]
    files: dict[str, bytes]
    job_id: str = "test"
    kind: str = "reconstruction"
    input_meta: dict[str, dict[str, Any]] = field(default_factory=dict)
    progress_calls: list[tuple[float, str]] = field(default_factory=list)

    def __post_init__(self) -> None:
        (self.root / "in").mkdir(parents=True, exist_ok=True)
        (self.root / "out").mkdir(parents=True, exist_ok=True)
        for name, data in self.files.items():
            (self.root / "in" / name).write_bytes(data)

    @property
    def inputs(self) -> dict[str, str]:
        return {name: f"blob/{name}" for name in self.files}

    def input_path(self, name: str) -> Path:
        return self.root / "in" / name

    def read_input(self, name: str) -> bytes:
        return self.input_path(name).read_bytes()

    def result_path(self, name: str) -> Path:
        return self.root / "out" / name

    def write_result(self, name: str, data: bytes) -> None:
        self.result_path(name).write_bytes(data)

    def progress(self, fraction: float, stage: str) -> None:
        self.progress_calls.append((fraction, stage))
