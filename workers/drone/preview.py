"""A preview image like the paper's Fig. 5: the point cloud and the cameras seen from the left
side, from the top and from the right side (orthographic, drawn with OpenCV).

"Up" is the cloud's direction of least spread (the ground normal for a drone survey), turned
towards the cameras; "left/right" look along the direction of second-least spread.
"""
from __future__ import annotations

import cv2
import numpy as np

from workers.common.images import encode_png

_BG = (40, 40, 40)
_CAM = (60, 60, 255)


def _frame(points: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Rows e1, e2, up (3, 3) of a right-handed viewing frame."""
    X = points if len(points) >= 3 else np.vstack([points, centres])
    lo, hi = np.percentile(X, [2, 98], axis=0)
    core = X[np.all((X >= lo) & (X <= hi), axis=1)]
    core = core if len(core) >= 3 else X
    _, _, Vt = np.linalg.svd(core - core.mean(0), full_matrices=False)
    e1, e2, up = Vt[0], Vt[1], np.cross(Vt[0], Vt[1])
    if len(centres) and np.dot(centres.mean(0) - core.mean(0), up) < 0:
        up, e2 = -up, -e2
    return np.stack([e1, e2, up])


def render_preview(points: np.ndarray, colors_bgr: np.ndarray, R: np.ndarray, t: np.ndarray,
                   panel: int = 420, label: str = "", frame: np.ndarray | None = None) -> np.ndarray:
    """Three panels side by side, (panel, 3 * panel, 3) uint8 BGR.

    points (N, 3), colors_bgr (N, 3) uint8, and the registered cameras' world-to-camera
    R (M, 3, 3), t (M, 3) in sequence order. ``label`` prefixes the panels' titles; ``frame``
    (3, 3) the viewing frame (rows e1, e2, up) to use instead of the cloud's own (two previews of
    one scene then look from the same directions).
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    centres = -np.einsum("nji,nj->ni", R, t) if len(R) else np.zeros((0, 3))
    out = np.full((panel, 3 * panel, 3), _BG, np.uint8)
    if len(points) + len(centres) < 2:
        return out
    F = _frame(points, centres) if frame is None else np.asarray(frame, np.float64)
    P, C = points @ F.T, centres @ F.T
    A = C.copy()
    if len(R):
        span = np.ptp(np.vstack([P, C]), axis=0).max() if len(P) else 1.0
        A = C + 0.06 * span * (R[:, 2, :] @ F.T)  # optical axes, for the camera markers
    allp = np.vstack([P, C])
    lo, hi = np.percentile(allp, 1, axis=0), np.percentile(allp, 99, axis=0)
    lo, hi = np.minimum(lo, C.min(0) if len(C) else lo), np.maximum(hi, C.max(0) if len(C) else hi)
    # (horizontal axis, sign), (vertical axis, sign), depth axis (drawn far to near), title
    views = [((0, 1), (2, 1), (1, -1), "left"), ((0, 1), (1, 1), (2, 1), "top"), ((0, -1), (2, 1), (1, 1), "right")]
    for k, ((ha, hs), (va, vs), (da, ds), title) in enumerate(views):
        img = out[:, k * panel:(k + 1) * panel]
        size = max(hi[ha] - lo[ha], hi[va] - lo[va], 1e-9)
        s = 0.86 * panel / size
        mid_h, mid_v = (hi[ha] + lo[ha]) / 2, (hi[va] + lo[va]) / 2

        def pix(Q: np.ndarray) -> np.ndarray:
            u = panel / 2 + hs * s * (Q[:, ha] - mid_h)
            v = panel / 2 - vs * s * (Q[:, va] - mid_v)
            return np.stack([u, v], 1)

        if len(P):
            uv = np.rint(pix(P)).astype(np.int64)
            order = np.argsort(ds * P[:, da])  # far first, near last (painter's order)
            uv, col = uv[order], colors_bgr[order]
            for du in (0, 1):
                for dv in (0, 1):
                    u, v = uv[:, 0] + du, uv[:, 1] + dv
                    ok = (u >= 0) & (v >= 0) & (u < panel) & (v < panel)
                    img[v[ok], u[ok]] = col[ok]
        if len(C):
            cu = np.rint(pix(C)).astype(np.int32)
            au = np.rint(pix(A)).astype(np.int32)
            cv2.polylines(img, [cu.reshape(-1, 1, 2)], False, _CAM, 1, cv2.LINE_AA)
            for a, b in zip(cu, au):
                cv2.line(img, tuple(int(x) for x in a), tuple(int(x) for x in b), (0, 200, 255), 1, cv2.LINE_AA)
                cv2.circle(img, tuple(int(x) for x in a), 2, _CAM, -1, cv2.LINE_AA)
        cv2.putText(img, f"{label} {title}".strip(), (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (230, 230, 230), 1,
                    cv2.LINE_AA)
        cv2.rectangle(img, (0, 0), (panel - 1, panel - 1), (90, 90, 90), 1)
    return out


def preview_png(points: np.ndarray, colors_bgr: np.ndarray, R: np.ndarray, t: np.ndarray, panel: int = 420,
                dense: tuple[np.ndarray, np.ndarray] | None = None, max_dense_points: int = 400_000) -> bytes:
    """:func:`render_preview` encoded as PNG; with ``dense`` (points (N, 3), colours (N, 3) uint8 BGR) a
    second row shows the dense cloud from the same directions (at most ``max_dense_points``, evenly
    subsampled), so the image is (2 * panel, 3 * panel)."""
    img = render_preview(points, colors_bgr, R, t, panel, "sparse" if dense is not None else "")
    if dense is not None:
        dp, dc = dense
        step = max(1, -(-len(dp) // max_dense_points))
        centres = -np.einsum("nji,nj->ni", R, t) if len(R) else np.zeros((0, 3))
        frame = _frame(np.asarray(points, np.float64).reshape(-1, 3), centres) if len(points) + len(centres) >= 3 \
            else None
        img = np.vstack([img, render_preview(dp[::step], dc[::step], R, t, panel, "dense", frame)])
    return encode_png(img, level=None)
