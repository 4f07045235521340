"""Reading "Bundle Adjustment in the Large" (BAL) problem files.

Format (Agarwal et al., ECCV 2010): a header ``n_cameras n_points n_observations``, then one
line ``camera point x y`` per observation, then 9 numbers per camera (Rodrigues rotation,
translation, f, k1, k2) and 3 per point, one number per line. Pixels are measured from the image
centre with y up; the camera looks down -z (see :class:`workers.drone.camera_models.BALModel`).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class BALProblem:
    """params (C, 9), points (P, 3), cam_idx/pt_idx (N,) int64, obs (N, 2) float64 pixels."""

    params: np.ndarray
    points: np.ndarray
    cam_idx: np.ndarray
    pt_idx: np.ndarray
    obs: np.ndarray


def read_bal(path: str | Path) -> BALProblem:
    """Parse a BAL text file; raises ValueError when the counts do not match the header."""
    with open(path, "r") as fh:
        header = fh.readline().split()
        if len(header) != 3:
            raise ValueError(f"{path}: the first line must hold 3 counts")
        n_cams, n_pts, n_obs = (int(v) for v in header)
        table = np.loadtxt(fh, max_rows=n_obs, ndmin=2)
        rest = np.fromstring(fh.read(), sep=" ")  # noqa: NPY201 - fast whitespace parse
    if table.shape != (n_obs, 4) or rest.size != 9 * n_cams + 3 * n_pts:
        raise ValueError(f"{path}: contents do not match the header {header}")
    return BALProblem(
        params=rest[: 9 * n_cams].reshape(n_cams, 9).copy(),
        points=rest[9 * n_cams:].reshape(n_pts, 3).copy(),
        cam_idx=table[:, 0].astype(np.int64),
        pt_idx=table[:, 1].astype(np.int64),
        obs=table[:, 2:4].copy(),
    )
