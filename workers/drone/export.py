"""Writing a :class:`~workers.drone.reconstruction.SparseModel`: coloured PLY, a COLMAP text
model, the trajectory as JSON; and the dense pass's outputs: its PLY (normals and views per point too), its
depth maps as 16-bit PNGs in a zip.

Pixel values go out at the media's native resolution. COLMAP measures pixels from the image
corner (the first pixel's centre is (0.5, 0.5)), our convention from the first pixel's centre,
so COLMAP coordinates are ours + 0.5.
"""
from __future__ import annotations

import io
import json
from typing import Any

import numpy as np

from workers.camera import rotation_to_quat
from workers.common.images import encode_png

from .geometry import camera_centre
from .reconstruction import SparseModel


DEPTH_PNG_LEVELS = 65535
"""A depth map PNG stores round(depth / scale), 0 = no depth."""

_PLY_TYPES = {"<f4": "float", "u1": "uchar"}


def ply_fields(normals: bool, views: bool) -> list[tuple[str, str]]:
    """The vertex properties of our PLY files: x y z, optionally nx ny nz, red green blue, optionally views."""
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")] if normals else []
    return fields + [("red", "u1"), ("green", "u1"), ("blue", "u1")] + ([("views", "u1")] if views else [])


PLY_DENSE_FIELDS = ply_fields(True, True)


def ply_header(count: int, fields: list[tuple[str, str]], comment: str) -> bytes:
    """The header of a binary little-endian PLY of ``count`` vertices with ``fields``."""
    return (f"ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {count}\n"
            + "".join(f"property {_PLY_TYPES[t]} {name}\n" for name, t in fields) + "end_header\n").encode("ascii")


def ply_rows(points: np.ndarray, colors_bgr: np.ndarray, normals: np.ndarray | None = None,
             views: np.ndarray | None = None) -> bytes:
    """The vertex rows of points (N, 3) (written as float32) with colours (N, 3) uint8 BGR, optionally normals
    (N, 3) and views (N,) uint8, in :func:`ply_fields` order (a PLY written in chunks appends these)."""
    fields = ply_fields(normals is not None, views is not None)
    v = np.empty(len(points), dtype=fields)
    for i, c in enumerate("xyz"):
        v[c] = points[:, i]
        if normals is not None:
            v["n" + c] = normals[:, i]
    v["red"], v["green"], v["blue"] = colors_bgr[:, 2], colors_bgr[:, 1], colors_bgr[:, 0]
    if views is not None:
        v["views"] = views
    return v.tobytes()


def ply_bytes(points: np.ndarray, colors_bgr: np.ndarray, normals: np.ndarray | None = None,
              views: np.ndarray | None = None, comment: str = "sweepcast drone reconstruction") -> bytes:
    """Binary little-endian PLY of points (N, 3) (model units, written as float32) with colours (N, 3) uint8
    BGR, optionally unit normals ``nx ny nz`` (N, 3) float32 and ``views`` (N,) uint8 (frames that agree on
    each point), as MeshLab and CloudCompare read it."""
    return (ply_header(len(points), ply_fields(normals is not None, views is not None), comment)
            + ply_rows(points, colors_bgr, normals, views))


def depth_png(depth: np.ndarray, far: float) -> tuple[bytes, float]:
    """16-bit PNG of a depth map (h, w) float32 (model units, 0 = none) and its scale (model units per
    level): level = round(depth / scale), scale = far / 65535, 0 = no depth."""
    scale = float(far) / DEPTH_PNG_LEVELS
    levels = np.clip(np.rint(depth / scale), 0, DEPTH_PNG_LEVELS).astype(np.uint16)
    levels[depth <= 0] = 0
    return encode_png(levels, level=None), scale


def depth_file_name(frame: str) -> str:
    """``<frame name without its image suffix>.png``, safe as a file name in a zip."""
    stem = frame.rsplit(".", 1)[0] if "." in frame else frame
    return ("".join(c if c.isalnum() or c in "-_." else "_" for c in stem) or "frame") + ".png"


def _native(model: SparseModel, xy: np.ndarray) -> np.ndarray:
    """Working-resolution pixels -> native-resolution pixels (our convention)."""
    return (xy + 0.5) / model.scale - 0.5


def colmap_text(model: SparseModel) -> dict[str, str]:
    """COLMAP text model: {'cameras.txt', 'images.txt', 'points3D.txt'} -> file contents.

    One camera (native resolution): PINHOLE, or RADIAL (f, cx, cy, k1, k2) for a self-calibrated lens
    with the points2D where the lens shows them; one image per registered frame, named after the
    frame; points2D of keyframes are their bundle-adjustment observations.
    """
    intr = model.intrinsics.scaled(1.0 / model.scale)
    w = int(round(model.width / model.scale))
    h = int(round(model.height / model.scale))
    if model.lens is not None and intr.dist is not None:
        camera = (f"1 RADIAL {w} {h} {intr.fx:.10g} {intr.cx + 0.5:.10g} {intr.cy + 0.5:.10g} "
                  f"{intr.dist[0]:.10g} {intr.dist[1]:.10g}\n")
    else:
        camera = f"1 PINHOLE {w} {h} {intr.fx:.10g} {intr.fy:.10g} {intr.cx + 0.5:.10g} {intr.cy + 0.5:.10g}\n"
    cameras = ("# Camera list with one line of data per camera:\n"
               "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n# Number of cameras: 1\n" + camera)
    frames = np.flatnonzero(model.registered)
    image_id = {int(f): i + 1 for i, f in enumerate(frames)}
    order = np.lexsort((model.obs_point, model.obs_frame))
    seen = model.obs_xy[order] if model.lens is None else model.lens.distort(model.obs_xy[order])
    of, op, xy = model.obs_frame[order], model.obs_point[order], _native(model, seen) + 0.5
    starts = np.searchsorted(of, frames)
    ends = np.searchsorted(of, frames, side="right")
    point2d_idx = np.empty(len(of), np.int64)
    img = io.StringIO()
    img.write("# Image list with two lines of data per image:\n"
              "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
              "#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
              f"# Number of images: {len(frames)}\n")
    for f, a, b in zip(frames, starts, ends):
        q = rotation_to_quat(model.R[f])
        t = model.t[f]
        img.write(f"{image_id[int(f)]} {q[0]:.12g} {q[1]:.12g} {q[2]:.12g} {q[3]:.12g} "
                  f"{t[0]:.12g} {t[1]:.12g} {t[2]:.12g} 1 {model.frame_name[f]}\n")
        point2d_idx[a:b] = np.arange(b - a)
        img.write(" ".join(f"{x:.3f} {y:.3f} {p + 1}" for (x, y), p in zip(xy[a:b], op[a:b])) + "\n")
    pts = io.StringIO()
    pts.write("# 3D point list with one line of data per point:\n"
              "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
              f"# Number of points: {len(model.points)}\n")
    by_point = np.argsort(op, kind="stable")
    bounds = np.searchsorted(op[by_point], np.arange(len(model.points) + 1))
    for j, (X, c, e) in enumerate(zip(model.points, model.colors, model.point_error / model.scale)):
        rows = by_point[bounds[j]:bounds[j + 1]]
        track = " ".join(f"{image_id[int(of[r])]} {point2d_idx[r]}" for r in rows)
        pts.write(f"{j + 1} {X[0]:.9g} {X[1]:.9g} {X[2]:.9g} {c[2]} {c[1]} {c[0]} {e:.4f} {track}\n")
    return {"cameras.txt": cameras, "images.txt": img.getvalue(), "points3D.txt": pts.getvalue()}


def _pose_item(R: np.ndarray, t: np.ndarray) -> dict[str, Any]:
    return {"R": R.tolist(), "t": t.tolist(), "center": camera_centre(R, t).tolist(),
            "quaternion_wxyz": rotation_to_quat(R).tolist()}


def trajectory(model: SparseModel) -> dict[str, Any]:
    """JSON-able trajectory: every decoded frame in order, with its pose when it has one.

    Each frame says whether frame selection tracked it (``selected``; else ``skipped_because``),
    whether it is a ``keyframe``, and how it got its pose (``registration``): 'map' (the
    incremental mapping and bundle adjustment; ``inliers`` = its observations in the final map) or
    'pnp' (registered afterwards by PnP against the map, ``inliers`` of ``candidates`` mapped points;
    selected frames are then refined with the map by the final bundle adjustment when ``joint_ba``).
    A frame without a pose has ``reason``. ``unregistered`` lists those frames again.
    """
    intr = model.intrinsics.scaled(1.0 / model.scale)
    n = len(model.frame_index)
    registration = model.frame_registration or ["map" if r else None for r in model.registered]
    failure = model.frame_failure or [None] * n
    frames = []
    for f in range(n):
        item: dict[str, Any] = {"frame": int(model.frame_index[f]), "name": model.frame_name[f],
                                "time": model.frame_time[f], "selected": True, "keyframe": bool(model.keyframe[f]),
                                "registered": bool(model.registered[f]), "registration": registration[f]}
        if len(model.frame_inliers):
            item["inliers"] = int(model.frame_inliers[f])
        if model.registered[f]:
            item.update(_pose_item(model.R[f], model.t[f]))
        else:
            item["reason"] = failure[f] or "not registered"
        frames.append(item)
    for view, loc in model.skipped:
        item = {"frame": view.index, "name": view.name, "time": view.time, "selected": False,
                "skipped_because": view.reason, "keyframe": False, "registered": loc.R is not None,
                "registration": "pnp" if loc.R is not None else None, "inliers": loc.inliers,
                "candidates": loc.candidates}
        if loc.R is not None:
            item.update(_pose_item(loc.R, loc.t))
        else:
            item["reason"] = loc.failure
        frames.append(item)
    frames.sort(key=lambda item: item["frame"])
    return {
        "convention": "world-to-camera x_cam = R X + t, OpenCV axes (x right, y down, z forward); the world is "
                      + (model.world or "the first reconstructed camera's frame, the unit the baseline of the initial "
                                        "pair"),
        "intrinsics": {"fx": intr.fx, "fy": intr.fy, "cx": intr.cx, "cy": intr.cy,
                       "width": int(round(model.width / model.scale)),
                       "height": int(round(model.height / model.scale))},
        "counts": {"decoded": len(frames), "selected": n, "keyframes": int(model.keyframe.sum()),
                   "registered": sum(item["registered"] for item in frames),
                   "registered_in_map": sum(item["registration"] == "map" for item in frames),
                   "registered_afterwards": sum(item["registration"] == "pnp" for item in frames)},
        "frames": frames,
        "unregistered": [{"frame": item["frame"], "name": item["name"], "reason": item["reason"]}
                         for item in frames if not item["registered"]],
    }


def trajectory_json(model: SparseModel) -> bytes:
    """:func:`trajectory` as UTF-8 JSON."""
    return json.dumps(trajectory(model), indent=1).encode()
