"""Merging a survey's submodels into one model: each submodel already lies in the survey's UTM frame by its own
GPS similarity; a small similarity more per submodel, found by least squares, makes the photos two submodels
share agree (their centres and their orientations) while the GPS holds the whole (the idea of OpenSfM's and
OpenDroneMap's submodel alignment: shared cameras and GPS; written here from that description).

Then every photo takes its pose from one submodel (the one whose core holds it, else one that registered it),
every sparse point from the submodel nearest to it (the cores' centres), so no photo or point appears twice.
"""
from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from ..evaluation import Sim3
from ..geo import SimilarityFit
from ..geometry import camera_centre, skew
from ..georef import Georeference, apply
from ..reconstruction import SparseModel

SHARED_CENTRE_SIGMA_M = 0.02
"""How closely two submodels' poses of one photo should agree (m): far tighter than the GPS."""
SHARED_ROTATION_SIGMA_RAD = 0.001
GPS_SIGMA_FLOOR_M = 0.05
"""The GPS terms' standard deviation is the submodel's own fit RMSE, at least this (exact synthetic GPS)."""


def _rotation_vector(R: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(R, np.float64))[0].ravel()


def _jacobian(X: np.ndarray, c: np.ndarray) -> np.ndarray:
    """d X' / d (omega, tau, sigma) (3, 7) of X' = X + sigma (X - c) + omega x (X - c) + tau."""
    v = X - c
    return np.hstack([-skew(v), np.eye(3), v[:, None]])


def _poses(model: SparseModel) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Photo position -> (camera centre (3,), R (3, 3)) of the model's registered frames."""
    return {int(model.frame_index[f]): (camera_centre(model.R[f], model.t[f]), model.R[f])
            for f in np.flatnonzero(model.registered)}


def alignment(models: dict[int, tuple[SparseModel, Georeference]], owner: np.ndarray, iterations: int = 3
              ) -> tuple[dict[int, Sim3], dict[str, Any]]:
    """The similarity per submodel (index -> :class:`Sim3`, near the identity) that makes the photos they share
    agree, the GPS of their own photos (their cores) holding the whole; ``owner`` (N,) the submodel whose core
    holds each photo. Moves nothing. Returns the similarities and the shared photos' disagreement before and
    after (centre RMSE, m; rotation RMSE, degrees)."""
    ids = sorted(models)
    col = {s: 7 * k for k, s in enumerate(ids)}
    poses = {s: _poses(m) for s, (m, _) in models.items()}
    centre = {s: np.mean([c for c, _ in poses[s].values()], axis=0) if poses[s] else np.zeros(3) for s in ids}
    total = {s: Sim3(1.0, np.eye(3), np.zeros(3)) for s in ids}
    shared = [(a, b, i) for ai, a in enumerate(ids) for b in ids[ai + 1:] for i in sorted(set(poses[a]) & set(poses[b]))]
    before = _disagreement(poses, shared)
    gps = {}
    for s, (m, ref) in models.items():
        sigma = max(ref.fit.rmse if np.isfinite(ref.fit.rmse) else 1.0, GPS_SIGMA_FLOOR_M)
        rows = [(int(m.frame_index[f]), xyz) for f, xyz, ok in zip(ref.frames, ref.targets, ref.fit.inliers)
                if ok and owner[int(m.frame_index[f])] == s]
        gps[s] = (rows, sigma)
    for _ in range(iterations if len(ids) > 1 else 0):
        A, r = [], []
        for a, b, i in shared:
            (Ca, Ra), (Cb, Rb) = poses[a][i], poses[b][i]
            row = np.zeros((3, 7 * len(ids)))
            row[:, col[a]:col[a] + 7] = _jacobian(Ca, centre[a])
            row[:, col[b]:col[b] + 7] -= _jacobian(Cb, centre[b])
            A.append(row / SHARED_CENTRE_SIGMA_M)
            r.append(-(Ca - Cb) / SHARED_CENTRE_SIGMA_M)
            row = np.zeros((3, 7 * len(ids)))
            row[:, col[b]:col[b] + 3] = np.eye(3)
            row[:, col[a]:col[a] + 3] = -np.eye(3)
            A.append(row / SHARED_ROTATION_SIGMA_RAD)
            r.append(_rotation_vector(Ra.T @ Rb) / SHARED_ROTATION_SIGMA_RAD)
        for s in ids:
            rows, sigma = gps[s]
            for i, xyz in rows:
                if i not in poses[s]:
                    continue
                row = np.zeros((3, 7 * len(ids)))
                row[:, col[s]:col[s] + 7] = _jacobian(poses[s][i][0], centre[s])
                A.append(row / sigma)
                r.append(-(poses[s][i][0] - xyz) / sigma)
        if not A:
            break
        delta = np.linalg.lstsq(np.vstack(A), np.concatenate(r), rcond=None)[0]
        for s in ids:
            omega, tau, sigma = delta[col[s]:col[s] + 3], delta[col[s] + 3:col[s] + 6], delta[col[s] + 6]
            R = cv2.Rodrigues(omega.reshape(3, 1))[0]
            step = Sim3(1.0 + sigma, R, centre[s] + tau - (1.0 + sigma) * R @ centre[s])
            total[s] = Sim3(step.s * total[s].s, step.R @ total[s].R, step.s * step.R @ total[s].t + step.t)
            poses[s] = {i: (step.apply(C[None])[0], Rc @ step.R.T) for i, (C, Rc) in poses[s].items()}
    return total, {"shared_photos": len({i for _, _, i in shared}), "shared_pairs": len(shared),
                   "before": before, "after": _disagreement(poses, shared)}


def _disagreement(poses: dict, shared: list) -> dict[str, float | None]:
    if not shared:
        return {"centre_rmse_m": None, "centre_max_m": None, "rotation_rmse_deg": None}
    d = np.array([np.linalg.norm(poses[a][i][0] - poses[b][i][0]) for a, b, i in shared])
    ang = np.array([np.degrees(np.linalg.norm(_rotation_vector(poses[a][i][1].T @ poses[b][i][1])))
                    for a, b, i in shared])
    return {"centre_rmse_m": float(np.sqrt(np.mean(d**2))), "centre_max_m": float(d.max()),
            "rotation_rmse_deg": float(np.sqrt(np.mean(ang**2)))}


def merge(models: dict[int, tuple[SparseModel, Georeference]], owner: np.ndarray, centres: np.ndarray,
          reference: int) -> tuple[SparseModel, Georeference, dict[str, Any]]:
    """One model of every photo from the submodels (module docstring): ``owner`` (N,) the submodel whose core
    holds each photo, ``centres`` (S, 2) the cores' centres (m), ``reference`` the submodel whose lens the others
    used (its intrinsics, lens report and georeference scale stand for the survey's). The submodels are moved by
    :func:`alignment` in place. Returns the model, its georeference and the merge's report."""
    sims, aligned = alignment(models, owner)
    for s, sim in sims.items():
        m, ref = models[s]
        apply(m, sim, m.world or "")
    base, base_ref = models[reference]
    chosen = _choose_frames(models, owner)
    positions = np.array(sorted(chosen), np.int64)
    F = len(positions)
    frame_of = {int(p): k for k, p in enumerate(positions)}
    R = np.tile(np.eye(3), (F, 1, 1))
    t = np.zeros((F, 3))
    names, registration, inliers, failure = [""] * F, [None] * F, np.zeros(F, np.int64), [None] * F
    registered = np.zeros(F, bool)
    for pos, (s, f) in chosen.items():
        m = models[s][0]
        k = frame_of[pos]
        names[k] = m.frame_name[f]
        if m.registered[f]:
            R[k], t[k], registered[k] = m.R[f], m.t[f], True
            registration[k] = m.frame_registration[f] if m.frame_registration else "map"
            inliers[k] = m.frame_inliers[f] if len(m.frame_inliers) else 0
        else:
            failure[k] = (m.frame_failure[f] if m.frame_failure and m.frame_failure[f] else
                          "not registered in its submodel")
    pts, cols, errs, of, op, oxy = [], [], [], [], [], []
    n_points = 0
    present = np.array(sorted(models), np.int64)
    for s, (m, _) in models.items():
        if len(m.points) == 0:
            continue
        near = present[np.argmin(np.linalg.norm(m.points[:, None, :2] - centres[None, present, :], axis=2), axis=1)]
        keep = near == s
        new_id = np.full(len(m.points), -1, np.int64)
        new_id[keep] = n_points + np.arange(int(keep.sum()))
        n_points += int(keep.sum())
        pts.append(m.points[keep])
        cols.append(m.colors[keep])
        errs.append(m.point_error[keep])
        mine = np.array([chosen.get(int(m.frame_index[f]), (-1, -1))[0] == s for f in range(len(m.frame_index))])
        use = (new_id[m.obs_point] >= 0) & mine[m.obs_frame]
        of.append(np.array([frame_of[int(m.frame_index[f])] for f in m.obs_frame[use]], np.int64))
        op.append(new_id[m.obs_point[use]])
        oxy.append(m.obs_xy[use])
    cat = (lambda xs, shape, dt: np.concatenate(xs) if xs else np.zeros(shape, dt))
    model = SparseModel(
        K=base.K, intrinsics=base.intrinsics, scale=base.scale, width=base.width, height=base.height,
        frame_index=positions, frame_time=[None] * F, frame_name=names, keyframe=registered.copy(),
        registered=registered, R=R, t=t, points=cat(pts, (0, 3), np.float64), colors=cat(cols, (0, 3), np.uint8),
        point_error=cat(errs, (0,), np.float64), obs_frame=cat(of, (0,), np.int64), obs_point=cat(op, (0,), np.int64),
        obs_xy=cat(oxy, (0, 2), np.float64), frame_registration=registration, frame_inliers=inliers,
        frame_failure=failure, lens=base.lens, world=base.world)
    model.report = _report(model, models, base, aligned)
    return model, _merged_georeference(model, models, owner, base_ref), aligned


def _choose_frames(models: dict[int, tuple[SparseModel, Georeference]], owner: np.ndarray) -> dict[int, tuple[int, int]]:
    """Photo position -> (submodel, its frame) each photo's pose comes from: its core's submodel when that one
    registered it, else the one that registered it with the most inliers, else its core's (unregistered)."""
    out: dict[int, tuple[int, int]] = {}
    best: dict[int, int] = {}
    for s, (m, _) in models.items():
        for f, pos in enumerate(m.frame_index):
            pos = int(pos)
            score = (2 if owner[pos] == s else 1) * 10**9 + (int(m.frame_inliers[f]) if len(m.frame_inliers) else 0)
            score = score if m.registered[f] else (1 if owner[pos] == s else 0)
            if pos not in out or score > best[pos]:
                out[pos], best[pos] = (s, f), score
    return out


def _report(model: SparseModel, models: dict, base: SparseModel, aligned: dict[str, Any]) -> dict[str, Any]:
    """The merged model's report, in the single model's shape (:func:`workers.drone.reconstruction._report`)."""
    P = np.einsum("nij,nj->ni", model.R[model.obs_frame], model.points[model.obs_point]) + model.t[model.obs_frame]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = P[:, :2] / P[:, 2:3] @ model.K[:2, :2].T + model.K[:2, 2]
    err = np.linalg.norm(uv - model.obs_xy, axis=1) if len(P) else np.zeros(0)
    err = err[np.isfinite(err)]
    subs = [m.report for m, _ in models.values()]
    before = [r["reprojection_error_px"]["before_ba"]["mean"] for r in subs
              if r["reprojection_error_px"]["before_ba"]["mean"] is not None]
    return {
        "media": dict(base.report["media"]),
        "frames": {"decoded": int(len(model.frame_index)), "selected": int(len(model.frame_index)),
                   "skipped_blurred": 0, "stride": 1, "keyframes": int(model.registered.sum()),
                   "keyframes_registered": int(model.registered.sum()), "registered": int(model.registered.sum()),
                   "localised_by_pnp": int(sum(r == "pnp" for r in model.frame_registration)),
                   "skipped_by_selection": 0, "skipped_registered": 0},
        "tracks": {"count": int(sum(r["tracks"]["count"] for r in subs)),
                   "observations": int(sum(r["tracks"]["observations"] for r in subs))},
        "matcher": base.report["matcher"],
        "points": int(len(model.points)),
        "observations_in_ba": int(len(model.obs_frame)),
        "reprojection_error_px": {
            "before_ba": {"mean": float(np.mean(before)) if before else None, "median": None},
            "after_ba": {"mean": float(err.mean()) if len(err) else None,
                         "median": float(np.median(err)) if len(err) else None}},
        "bundle_adjustment": {"per_submodel": True, **{k: base.report["bundle_adjustment"].get(k)
                                                      for k in ("rounds", "loss", "termination")}},
        "intrinsics": dict(base.report["intrinsics"]),
        "submodel_alignment": aligned,
        "timings_s": {},
        "warnings": [w for r in subs for w in r.get("warnings", [])],
    }


def _merged_georeference(model: SparseModel, models: dict, owner: np.ndarray, base_ref: Georeference) -> Georeference:
    """The survey's georeference: every GPS frame of the merged model (the inliers of their own submodel's fit),
    residuals as the merged model stands; the reference submodel's similarity stands for the scale."""
    frames, targets, inl, notes = [], [], [], list(base_ref.notes)
    frame_of = {int(p): k for k, p in enumerate(model.frame_index)}
    for s, (m, ref) in models.items():
        for f, xyz, ok in zip(ref.frames, ref.targets, ref.fit.inliers):
            pos = int(m.frame_index[f])
            if owner[pos] == s and pos in frame_of and model.registered[frame_of[pos]]:
                frames.append(frame_of[pos])
                targets.append(xyz)
                inl.append(bool(ok))
    frames_a = np.asarray(frames, np.int64)
    targets_a = np.asarray(targets, np.float64).reshape(-1, 3)
    centres = np.stack([camera_centre(model.R[f], model.t[f]) for f in frames_a]) if len(frames_a) else targets_a
    residuals = np.linalg.norm(centres - targets_a, axis=1)
    fit = SimilarityFit(base_ref.sim, np.asarray(inl, bool), residuals, max(r.fit.threshold for _, r in models.values()),
                        any(r.fit.collinear for _, r in models.values()))
    notes.append(f"{len(models)} submodels, each placed by its own GPS and aligned by the photos they share "
                 "(report.json -> submodel_alignment); scale: the reference submodel's")
    return Georeference(base_ref.sim, base_ref.epsg, base_ref.origin, frames_a, targets_a, fit, base_ref.source,
                        base_ref.altitude, notes)
