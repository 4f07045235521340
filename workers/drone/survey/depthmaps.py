"""The dense stage's first half as tasks: one depth map per reference frame (:func:`workers.drone.dense.depth_map`,
the ZNCC plane sweep against its best neighbours), written to the job's work area with its 16-bit PNG.

The job chooses each reference's neighbours and depth range from the sparse model (:func:`plan_depth_maps`, as
:func:`workers.drone.dense.densify_views` does, scoring only the frames whose cameras are near: a survey of thousands
of photos never compares each with all), then sends the references in blocks of neighbouring frames
(:data:`REFS_PER_TASK`), so a task decodes a neighbour once for several references.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from scipy.spatial import cKDTree

from ..dense import depth_map
from ..dense.neighbours import depth_range, neighbours_by_centres, visible_points
from ..export import depth_file_name, depth_png
from ..frames import sharpness
from ..geometry import camera_centre
from ..reconstruction import SparseModel
from .mapjob import MapJob, Pose

REFS_PER_TASK = 6
"""Most references a task makes depth maps for (a task decodes each neighbour once for all of them)."""
CANDIDATES_PER_NEIGHBOUR = 4
"""A reference's neighbours are chosen among this many times ``dense_neighbours`` frames nearest to it."""
MIN_OBSERVED = 30
"""Fewer observed sparse points than this: the points in view stand for what a frame sees."""


@dataclass(frozen=True)
class DepthSpec:
    """One reference: its pose, the sweep's depth range (near, far) and its neighbours' frames (best first)."""

    pose: Pose
    near: float
    far: float
    neighbours: tuple[int, ...]


def pose_of(model: SparseModel, f: int) -> Pose:
    return Pose(int(f), model.frame_name[f], model.R[f].copy(), model.t[f].copy())


def plan_depth_maps(model: SparseModel, job: MapJob, refs: np.ndarray, by_view: bool = False
                    ) -> tuple[list[DepthSpec], list[dict[str, Any]]]:
    """The :class:`DepthSpec` of each reference frame ``refs`` (model frames) and, for those that get no depth map,
    a report item saying why (no neighbour shares sparse points, too few points in view). What a frame sees of the
    sparse points: its observations (fewer than :data:`MIN_OBSERVED`, or ``by_view``: the points in its view; a
    model merged from submodels, whose neighbouring photos observe points of different submodels, needs that)."""
    p = job.params
    centres = np.stack([camera_centre(model.R[f], model.t[f]) for f in refs])
    observed = model.points_by_frame()
    point_tree = cKDTree(model.points[:, :2]) if len(model.points) else None
    cameras = [job.dense_camera(pose_of(model, f)) for f in refs]
    seen = []
    for f, cam in zip(refs, cameras):
        obs = np.unique(observed[f])
        if (by_view or len(obs) < MIN_OBSERVED) and point_tree is not None:
            near = np.asarray(point_tree.query_ball_point(cam.center[:2], _reach(model, cam)), np.int64)
            obs = near[visible_points(cam, model.points[near])] if len(near) else near
        seen.append(obs)
    count = min(len(refs) - 1, CANDIDATES_PER_NEIGHBOUR * p.dense_neighbours + 1)
    _, cand = cKDTree(centres).query(centres, k=max(count, 1) + 1) if len(refs) > 1 else (None, None)
    specs, skipped = [], []
    for i, f in enumerate(refs):
        candidates = [int(j) for j in np.atleast_1d(cand[i]) if j < len(refs) and j != i] if cand is not None else []
        nb = neighbours_by_centres(centres, model.points, seen, i, p.dense_neighbours, candidates)
        rng = depth_range(cameras[i], model.points[seen[i]] if len(seen[i]) >= 10 else model.points)
        if not nb or rng is None:
            skipped.append({"frame": model.frame_name[f], "neighbours": [model.frame_name[refs[j]] for j in nb],
                            "skipped": "no other frame shares sparse points" if not nb
                            else "too few sparse points in view"})
            continue
        specs.append(DepthSpec(pose_of(model, f), rng[0], rng[1], tuple(int(refs[j]) for j in nb)))
    return specs, skipped


def _reach(model: SparseModel, camera) -> float:
    """How far from below the camera a frame may see sparse points: its height above the median point (a nadir
    frame of 70 degrees sees 0.85 of it to a corner) with room for tilt."""
    height = abs(camera.center[2] - (np.median(model.points[:, 2]) if len(model.points) else 0.0))
    return 1.2 * max(height, 1e-6)


def depth_name(frame: int) -> str:
    return f"depth/{frame:06d}"


@dataclass(frozen=True)
class DepthItem:
    """A block of references and the poses of every frame they need (references and neighbours)."""

    job: MapJob
    refs: tuple[DepthSpec, ...]
    poses: tuple[Pose, ...]


def depth_maps(item: DepthItem) -> list[dict[str, Any]]:
    """Make and write the depth maps of a block of references (those an earlier attempt wrote are kept); returns
    each one's report item (frame, neighbours, near, far, seconds, valid fraction, PNG name, depth scale) with its
    frame's ``sharpness`` (the orthophoto's choice of frame)."""
    job, work, p = item.job, item.job.work, item.job.params
    todo = [r for r in item.refs if not work.exists(depth_name(r.pose.frame) + ".json")]
    pending = {r.pose.frame for r in todo}
    out = {r.pose.frame: work.get_json(depth_name(r.pose.frame) + ".json") for r in item.refs
           if r.pose.frame not in pending}
    if todo:
        wanted = {r.pose.frame for r in todo} | {n for r in todo for n in r.neighbours}
        views = job.dense_views([q for q in item.poses if q.frame in wanted])
        names = {q.frame: q.name for q in item.poses}
        for r in todo:
            f = r.pose.frame
            nbs = [n for n in r.neighbours if n in views]
            if f not in views or not nbs:
                meta = {"frame": r.pose.name, "neighbours": [names[n] for n in r.neighbours],
                        "skipped": "its photo or its neighbours' could not be read"}
            else:
                dm = depth_map(views[f], [views[n] for n in nbs], r.near, r.far, p.dense_planes,
                               p.dense_window // 2, min(p.dense_best_k, len(nbs)), p.dense_min_texture,
                               p.dense_max_cost, p.dense_aggregation, coarse_to_fine=p.dense_coarse_to_fine)
                png, scale = depth_png(dm.depth, r.far)
                work.put_arrays(depth_name(f) + ".npz", depth=dm.depth)
                work.put(depth_name(f) + ".png", png)
                gray = cv2.cvtColor(views[f].image, cv2.COLOR_BGR2GRAY)
                meta = {"frame": r.pose.name, "neighbours": [names[n] for n in nbs], "near": r.near, "far": r.far,
                        "seconds": round(dm.seconds, 3), "valid_fraction": float((dm.depth > 0).mean()),
                        "file": depth_file_name(r.pose.name), "depth_scale": scale, "sharpness": sharpness(gray),
                        "neighbour_frames": nbs}
            meta["model_frame"] = f
            work.put_json(depth_name(f) + ".json", meta)
            out[f] = meta
    return [out[r.pose.frame] for r in item.refs]


def depth_items(job: MapJob, specs: list[DepthSpec], model: SparseModel, parallelism: int = 1) -> list[DepthItem]:
    """The references in blocks of consecutive frames, each with the poses it needs: at most
    :data:`REFS_PER_TASK` references a block, in a whole number of rounds of ``parallelism`` blocks of about equal
    size (:func:`block_size`)."""
    items = []
    size = block_size(len(specs), parallelism)
    for k in range(0, len(specs), size):
        block = tuple(specs[k:k + size])
        frames = sorted({s.pose.frame for s in block} | {n for s in block for n in s.neighbours})
        items.append(DepthItem(job, block, tuple(pose_of(model, f) for f in frames)))
    return items


def block_size(references: int, parallelism: int) -> int:
    """References per block: as many as :data:`REFS_PER_TASK` allows, but evened out over the rounds of
    ``parallelism`` tasks the blocks need, so that the last round does not leave CPUs idle (30 references in blocks
    of 6 on 2 CPUs ran as 2 + 2 + 1 tasks: the third round on one CPU; in blocks of 5, 2 + 2 + 2)."""
    cpus = max(1, parallelism)
    rounds = max(1, math.ceil(references / (cpus * REFS_PER_TASK)))
    return max(1, math.ceil(references / (cpus * rounds)))
