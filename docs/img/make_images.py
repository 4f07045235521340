"""Render the documentation's pictures with the project's own engines (run from the repository root):

    .venv/bin/python docs/img/make_images.py

- ``viewer.png``: what the browser viewer shows on the demo rig: five of its ten cameras (the studio's first
  recorded frame), the sweep renderer's virtual view from an orbit between them (the paper's weighting, 48
  planes) and that view's region map (one colour per single-camera region, black where two cameras blend).
- ``reconstruction.png``: the drone reconstructor's own ``preview.png`` (sparse and dense clouds with the camera
  path, three directions) of a generated 36-frame flight over a town, made by ``sweepcast reconstruct --dense``.
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
OUT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))


def _label(img: np.ndarray, text: str) -> np.ndarray:
    img = img.copy()
    cv2.rectangle(img, (0, 0), (11 * len(text) + 14, 30), (255, 255, 255), -1)
    cv2.putText(img, text, (7, 21), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (30, 30, 30), 1, cv2.LINE_AA)
    return img


def viewer_picture() -> np.ndarray:
    from workers.streaming.demo import demo_rig, demo_scene
    from workers.streaming.params import Orbit
    from workers.streaming.viewpoint import orbit_camera, orbit_frame
    from workers.sweep.overlays import regions_image
    from workers.sweep.renderer import RenderOptions, SweepRenderer
    from workers.synth import render_views

    rig = demo_rig()
    views = render_views(demo_scene(0.0), list(rig.cameras), with_background=True)
    renderer = SweepRenderer(rig, [v.image for v in views], backgrounds=[v.background for v in views])
    frame = orbit_frame(rig)
    between = float(np.mean(frame.azimuths[4:6])) + 0.3 * float(np.diff(frame.azimuths[4:6])[0])
    virtual = orbit_camera(frame, Orbit(azimuth=between), 50.0, (640, 480))
    result = renderer.render(virtual, RenderOptions(planes=48, method="kojima"))
    cams = [cv2.resize(_label(views[i].image, rig.cameras[i].name), (256, 192), interpolation=cv2.INTER_AREA)
            for i in range(0, 10, 2)]
    top = np.hstack(cams)
    bottom = np.hstack([_label(result.image, "virtual view (kojima, 48 planes)"),
                        _label(regions_image(result.regions, result.primary), "regions: cameras blended")])
    return np.vstack([top, bottom])


def reconstruction_picture(tmp: Path) -> np.ndarray:
    from workers.synth.flight import encode_video, flight_cameras, render_flight, terrain_scene

    cams = flight_cameras(36, length=30.0, altitude=25.0, sway=3.0, width=320, height=240, fov_deg=70,
                          shake_deg=0.2, seed=3)
    video = encode_video(render_flight(terrain_scene(3, extent=80.0, n_buildings=10, n_trees=12), cams),
                         tmp / "flight.mp4", fps=25)
    K = cams[0].K
    subprocess.run([sys.executable, "-m", "app", "reconstruct", str(video), "--dense", "--out", str(tmp / "recon"),
                    "--intrinsics", f"{K[0, 0]},{K[1, 1]},{K[0, 2]},{K[1, 2]}"], cwd=ROOT, check=True)
    return cv2.imread(str(tmp / "recon" / "preview.png"), cv2.IMREAD_COLOR)


def main() -> int:
    cv2.imwrite(str(OUT / "viewer.png"), viewer_picture(), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    with tempfile.TemporaryDirectory(prefix="sweepcast-docs-") as tmp:
        cv2.imwrite(str(OUT / "reconstruction.png"), reconstruction_picture(Path(tmp)),
                    [cv2.IMWRITE_PNG_COMPRESSION, 9])
    return 0


if __name__ == "__main__":
    sys.exit(main())
