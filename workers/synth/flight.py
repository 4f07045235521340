"""A synthetic drone flight with known poses: terrain with buildings and trees, a smooth path,
optional camera shake, motion blur and sensor noise, encoded to a video with PyAV (libx264).

World frame: z up, metres (as the rest of :mod:`workers.synth`). Cameras are
:class:`workers.camera.Camera` (world-to-camera R, t; OpenCV axes).

- ``terrain_scene(seed)``: textured ground plane, box buildings, spherical tree crowns.
- ``flight_cameras(n_frames, ...)``: one camera per frame along a gentle S-curve, looking forward
  and down (``tilt_deg`` from nadir), with optional smooth shake.
- ``render_flight(scene, cameras, motion_blur=..., noise_sigma=...)``: BGR frames.
- ``encode_video(frames, path, fps)``: an H.264 MP4.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import av
import numpy as np

from workers.camera import Camera, interpolate

from .raycast import render
from .scene import Box, Material, Plane, Scene, Sphere
from .textures import ColorNoise, Noise


def terrain_scene(seed: int = 0, extent: float = 160.0, n_buildings: int = 18, n_trees: int = 30) -> Scene:
    """Ground z = 0 with a detailed colour-noise texture, ``n_buildings`` boxes (4-18 m tall) and
    ``n_trees`` spherical crowns (radius 2-4 m, 3-7 m up), placed in a square of side ``extent``
    around the origin; deterministic in ``seed``."""
    rng = np.random.default_rng(seed)
    objects: list = [Plane(material=Material(ColorNoise(scale=1.5, octaves=6, seed=seed * 101 + 7, contrast=300.0)))]
    half = extent / 2
    for k in range(n_buildings):
        sx, sy = rng.uniform(6.0, 16.0, size=2)
        hz = rng.uniform(4.0, 18.0)
        cx, cy = rng.uniform(-half, half, size=2)
        dark = tuple(float(v) for v in rng.uniform(20, 90, size=3))
        light = tuple(float(v) for v in rng.uniform(170, 250, size=3))
        tex = Noise(dark, light, scale=1.5, octaves=6, seed=seed * 1000 + k)
        objects.append(Box((float(cx), float(cy), hz / 2), (float(sx), float(sy), float(hz)), Material(tex),
                           yaw_deg=float(rng.uniform(0, 90))))
    for k in range(n_trees):
        r = rng.uniform(2.0, 4.0)
        cx, cy = rng.uniform(-half, half, size=2)
        tex = Noise((20.0, 70.0, 20.0), (90.0, 200.0, 110.0), scale=0.8, octaves=5, seed=seed * 2000 + k)
        objects.append(Sphere((float(cx), float(cy), float(r + rng.uniform(1.0, 3.0))), float(r), Material(tex)))
    return Scene(tuple(objects))


def flight_cameras(
    n_frames: int, *, length: float = 80.0, altitude: float = 40.0, sway: float = 6.0, tilt_deg: float = 30.0,
    fov_deg: float = 70.0, width: int = 640, height: int = 480, shake_deg: float = 0.0, seed: int = 0,
) -> list[Camera]:
    """Cameras along a smooth path from y = -length/2 to +length/2 at about ``altitude`` m.

    The path sways ``sway`` m sideways (an S-curve) and climbs 2 m in the middle; each camera
    looks along the direction of flight, ``tilt_deg`` up from straight down. ``shake_deg`` adds
    a smooth random wobble (standard deviation per axis, degrees).
    """
    if n_frames < 2:
        raise ValueError("a flight needs at least two frames")
    s = np.linspace(0.0, 1.0, n_frames)
    pos = np.stack([sway * np.sin(2 * np.pi * s), length * (s - 0.5), altitude + 2.0 * np.sin(np.pi * s)], axis=1)
    vel = np.gradient(pos, axis=0)
    shake = _smooth_noise(n_frames, seed) * np.radians(shake_deg)
    cams = []
    for i in range(n_frames):
        d = vel[i, :2] / np.linalg.norm(vel[i, :2])
        fwd = np.array([d[0], d[1], 0.0])
        look = fwd * np.sin(np.radians(tilt_deg)) - np.array([0.0, 0.0, np.cos(np.radians(tilt_deg))])
        cam = Camera.look_at(f"frame{i:04d}", pos[i], pos[i] + look, up=fwd if tilt_deg < 60 else (0, 0, 1),
                             fov_deg=fov_deg, width=width, height=height)
        if shake_deg > 0:
            cam = Camera(cam.name, cam.K, _rotation(shake[i]) @ cam.R, _rotation(shake[i]) @ cam.t, width, height)
        cams.append(cam)
    return cams


def _smooth_noise(n: int, seed: int, width: float = 6.0) -> np.ndarray:
    """(n, 3) Gaussian-smoothed white noise with unit standard deviation per column."""
    rng = np.random.default_rng(seed)
    raw = rng.standard_normal((n + 40, 3))
    k = np.exp(-0.5 * (np.arange(-20, 21) / width) ** 2)
    out = np.stack([np.convolve(raw[:, c], k, mode="same") for c in range(3)], axis=1)[20:20 + n]
    return out / np.maximum(out.std(axis=0), 1e-12)


def _rotation(v: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(v))
    if th < 1e-15:
        return np.eye(3)
    k = v / th
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * Kx + (1 - np.cos(th)) * Kx @ Kx


def visible_part(scene: Scene, cam: Camera) -> Scene:
    """The scene without the boxes and spheres that lie wholly outside the camera's view (speed)."""
    keep = []
    for obj in scene.objects:
        if isinstance(obj, Box):
            centre, radius = np.asarray(obj.center, np.float64), 0.5 * float(np.linalg.norm(obj.size))
        elif isinstance(obj, Sphere):
            centre, radius = np.asarray(obj.center, np.float64), float(obj.radius)
        else:
            keep.append(obj)
            continue
        z = float(cam.R[2] @ centre + cam.t[2])
        if z <= -radius:
            continue
        if z > radius:
            uv, _ = cam.project(centre[None])
            margin = radius * max(cam.K[0, 0], cam.K[1, 1]) / (z - radius)
            u, v = uv[0]
            if u < -margin or v < -margin or u > cam.width - 1 + margin or v > cam.height - 1 + margin:
                continue
        keep.append(obj)
    return replace(scene, objects=tuple(keep))


def render_flight(
    scene: Scene, cameras: list[Camera], *, motion_blur: float = 0.0, blur_samples: int = 5,
    noise_sigma: float = 0.0, supersample: int = 1, seed: int = 0,
) -> list[np.ndarray]:
    """Frames (H, W, 3) uint8 BGR for ``cameras``.

    ``motion_blur``: fraction of the interval to the neighbouring frames during which the shutter
    is open (0: sharp), centred on each camera, sampled with ``blur_samples`` renders;
    ``noise_sigma``: Gaussian sensor noise in grey levels.
    """
    rng = np.random.default_rng(seed)
    frames = []
    n = len(cameras)
    for i, cam in enumerate(cameras):
        if motion_blur > 0 and n > 1:
            acc = np.zeros((cam.height, cam.width, 3))
            for u in np.linspace(-motion_blur / 2, motion_blur / 2, blur_samples):
                j = min(max(i + (1 if u >= 0 else -1), 0), n - 1)
                sub = cam if j == i else interpolate(cam, cameras[j], abs(float(u)))
                acc += render(visible_part(scene, sub), sub, supersample=supersample, with_background=False).image
            img = acc / blur_samples
        else:
            img = render(visible_part(scene, cam), cam, supersample=supersample, with_background=False).image.astype(np.float64)
        if noise_sigma > 0:
            img = img + rng.normal(0.0, noise_sigma, img.shape)
        frames.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    return frames


def encode_video(frames: list[np.ndarray], path: str | Path, fps: float = 25.0, crf: int = 18) -> Path:
    """Write BGR frames (same even size) as H.264 (libx264, yuv420p) to ``path``."""
    path = Path(path)
    h, w = frames[0].shape[:2]
    if w % 2 or h % 2:
        raise ValueError(f"H.264 needs even frame sizes, got {w}x{h}")
    with av.open(str(path), "w") as out:
        stream = out.add_stream("libx264", rate=int(round(fps)))
        stream.width, stream.height = w, h
        stream.pix_fmt = "yuv420p"
        stream.options = {"crf": str(crf), "preset": "veryfast"}
        for img in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="bgr24")):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    return path


