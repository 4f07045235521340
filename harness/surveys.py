"""Small synthetic nadir surveys for the tests and the benchmarks: geotagged JPEGs (a lens with barrel distortion,
no intrinsics given) over a scene with buildings and trees, rendered in a few seconds."""
from __future__ import annotations

import io
import zipfile
from pathlib import Path

from workers.synth.flight import render_flight
from workers.synth.survey import survey_cameras, survey_scene, write_geotagged_stills

ORIGIN = (431000.0, 5205000.0, 400.0)  # UTM 32N: the scene's (0, 0, 0)
EPSG = 32632


def small_survey(folder: Path, area: tuple[float, float] = (24.0, 20.0), supersample: int = 1):
    """Render a survey of ``area`` (m) at 60 m, 320x240 stills with 85 % forward and 75 % side overlap, into
    ``folder``; returns (scene, cameras, frames, paths)."""
    scene = survey_scene(2, extent=120.0, n_buildings=6, n_trees=10)
    cams = survey_cameras(area, 60.0, width=320, height=240, fov_deg=70.0, forward_overlap=0.85,
                          side_overlap=0.75, jitter_deg=1.0, dist=(-0.04, 0.0, 0.0, 0.0), seed=2)
    frames = render_flight(scene, cams, noise_sigma=1.0, supersample=supersample, seed=2)
    paths = write_geotagged_stills(folder, frames, cams, EPSG, ORIGIN, focal_35mm=25)
    return scene, cams, frames, paths


def zipped(paths: list[Path]) -> bytes:
    """The stills as a zip, in a folder as a user's archive has them."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for p in paths:
            zf.write(p, f"flight/{p.name}")
    return buf.getvalue()


def small_survey_zip(folder: Path) -> bytes:
    """:func:`small_survey` as a zip."""
    return zipped(small_survey(folder)[3])
