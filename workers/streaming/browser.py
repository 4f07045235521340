"""What a viewer that renders in its own browser (app/static/render, WebGL2) needs from the server: the rig's
geometry once (:func:`render_spec`), then frame sets as images the browser decodes itself (:func:`frame_atlas`).

A frame set travels as one image, an atlas of every camera's frame in rig order, ``atlas_columns(n)`` cells per
row, each cell the size of the largest camera image (smaller images at its top left, black around them),
undistorted (the spec's calibration then has no distortion) and shrunk by the session's source factor
(:func:`workers.streaming.session.source_factor`), so that the browser sweeps exactly the pixels the server's
renderer would. The empty-scene images travel the same way.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import cv2
import numpy as np

from workers.sweep.overlays import BLEND3_COLOR, BLEND_COLOR, PALETTE
from workers.sweep.rig import Rig
from workers.sweep.silhouette import BG_THRESHOLD, HULL_DILATE_PX, cleaning_disk
from workers.sweep.undistort import undistort_maps, undistorted

from .images import decode_stored
from .rules import renderer_rules
from .session import MAX_SOURCE_FACTOR, OVERLAY_WEIGHT, shrunk_images, shrunk_rig, views_up_to


def atlas_columns(cameras: int) -> int:
    """Cells per row of a frame-set atlas of ``cameras`` images: about square for equal cells."""
    return max(1, math.ceil(math.sqrt(cameras)))


def frame_atlas(images: Sequence[np.ndarray], rig: Rig, factor: int) -> np.ndarray:
    """The atlas (H, W, 3) uint8 BGR of one frame set: ``images`` ((h, w, 3) uint8 per camera, at the recorded
    size of ``rig``'s cameras) shrunk by ``factor`` (area averaging, as a recording session does) and undistorted
    with the shrunk calibration, placed in cells of the largest shrunk size (module docstring)."""
    small = shrunk_rig(rig, factor)
    shrunk = shrunk_images(images, small)
    cell_w = max(c.width for c in small.cameras)
    cell_h = max(c.height for c in small.cameras)
    columns = atlas_columns(len(small.cameras))
    rows = -(-len(small.cameras) // columns)
    atlas = np.zeros((rows * cell_h, columns * cell_w, 3), np.uint8)
    for i, (cam, img) in enumerate(zip(small.cameras, shrunk)):
        y, x = (i // columns) * cell_h, (i % columns) * cell_w
        atlas[y:y + cam.height, x:x + cam.width] = undistorted(undistort_maps(cam), img)
    return atlas


def render_spec(rig: Rig) -> dict[str, Any]:
    """The rig as app/static/render/rig.js takes it (JSON-able), beside what the hello already says (the cameras'
    names and sizes, the orbit frame): each camera's pose, its pinhole calibration at every source factor the server
    shrinks frames by (:func:`frame_sources`; frames arrive undistorted), the focus point and radius behind the
    automatic depth range, the rig's depth range if it has one, the atlas layout, how silhouettes are made, the
    overlay colours (RGB), and the renderer's rules (:func:`workers.streaming.rules.renderer_rules`)."""
    disk = cleaning_disk()
    ramp = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cv2.COLORMAP_TURBO)[:, 0, ::-1]
    return {
        "poses": [{"R": c.R.tolist(), "t": c.t.tolist()} for c in rig.cameras],
        "sources": frame_sources(rig),
        "focus": rig.focus_point().tolist(), "radius": rig.radius(),
        "depth_range": list(rig.depth_range) if rig.depth_range else None,
        "atlas_columns": atlas_columns(len(rig)),
        "silhouettes": {
            "threshold": BG_THRESHOLD, "dilate": HULL_DILATE_PX,
            "clean": [[int(dx) - disk.shape[1] // 2, int(dy) - disk.shape[0] // 2] for dy, dx in np.argwhere(disk)],
        },
        "style": {
            "palette": [[int(v) for v in bgr[::-1]] for bgr in PALETTE], "blend2": list(BLEND_COLOR[::-1]),
            "blend3": list(BLEND3_COLOR[::-1]), "weight": OVERLAY_WEIGHT, "colour_map": ramp.tolist(),
        },
        "rules": renderer_rules(),
    }


def frame_sources(rig: Rig) -> list[dict[str, Any]]:
    """The frames a recording's views sweep, one entry per source factor f = 1..MAX_SOURCE_FACTOR:
    ``{"factor": f, "views_up_to": [w, h], "cameras": [{"K", "width", "height"}]}``, the cameras' calibration
    for frames shrunk by f (:func:`workers.streaming.session.shrunk_rig`, rig order). A view of width x height px
    sweeps the frames of the largest factor whose ``views_up_to`` holds it, factor 1 where none does
    (:func:`workers.streaming.session.source_factor`)."""
    return [{"factor": f, "views_up_to": list(views_up_to(rig, f)),
             "cameras": [{"K": c.K.tolist(), "width": c.width, "height": c.height} for c in shrunk_rig(rig, f).cameras]}
            for f in range(1, MAX_SOURCE_FACTOR + 1)]


ATLAS_FORMATS = {"jpeg": (".jpg", "image/jpeg"), "png": (".png", "image/png")}


def encode_atlas(atlas: np.ndarray, image_format: str, quality: int) -> bytes:
    """An atlas (H, W, 3) uint8 BGR as the bytes of a ``jpeg`` (``quality`` 1..100, 4:2:0) or lossless ``png``
    file (PNG at OpenCV's fastest level: a frame set is encoded once and then cached)."""
    ext, _ = ATLAS_FORMATS[image_format]
    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)] if image_format == "jpeg" else [cv2.IMWRITE_PNG_COMPRESSION, 1]
    ok, data = cv2.imencode(ext, atlas, params)
    if not ok:
        raise ValueError(f"could not encode the atlas as {image_format}")
    return data.tobytes()


def live_background_atlas(pngs: Sequence[bytes], rig: Rig) -> bytes:
    """A live session's background model (one PNG per camera, at the size the session works at, at most the
    camera's) as a lossless PNG atlas at the cameras' calibrated size (bilinear where the model is smaller, as
    the session's own model grows: :meth:`BackgroundModel.resize`), undistorted like the frames."""
    images = []
    for cam, data in zip(rig.cameras, pngs):
        image = decode_stored(data, (cam.width, cam.height))
        if image.shape[:2] != (cam.height, cam.width):
            image = cv2.resize(image, (cam.width, cam.height), interpolation=cv2.INTER_LINEAR)
        images.append(image)
    return encode_atlas(frame_atlas(images, rig, 1), "png", 0)
