"""The four colour weightings, as small compiled functions shared by the renderer's kernel and tests.

Angles are between the ray from a camera centre to the surface point and the virtual view's ray to
the same point (the paper's Fig. 1); cameras are compared by the cosines of those angles.

- ``global``: one camera for the whole view, the one whose optical axis is closest to the virtual
  view's (Fig. 6(a)); :func:`global_camera`.
- ``nearest``: per pixel, the camera with the smallest angle (the primary camera; Fig. 4(a)).
- ``ulr``: unstructured-lumigraph k-nearest weighting (Buehler et al., as used by Matusik et al.):
  ``w_i = 1 - theta_i / theta_th``, normalised, where ``theta_th`` is the angle of the next-nearest
  camera beyond the k blended ones (so k cameras get non-zero weights, as in Fig. 5(a-c), N = k;
  with the threshold taken from the k-th camera itself, k = 2 would collapse to ``nearest``).
- ``kojima``: the paper's eqs. 1-6: primary and secondary cameras by cosine,
  ``D12 = cos th1 - cos th2``; ``D12 >= D_bnd``: one-camera region, ``C = C1``; otherwise
  ``C = 1/2 (1 + D12/D_bnd) C1 + 1/2 (1 - D12/D_bnd) C2``.
"""
from __future__ import annotations

import numpy as np
from numba import njit

METHODS = ("global", "nearest", "ulr", "kojima")
METHOD_CODES = {m: i for i, m in enumerate(METHODS)}


@njit(cache=True)
def kojima_weights(cos1: float, cos2: float, d_bnd: float) -> tuple[float, float]:
    """Eq. 6: weights (w1, w2) of the primary and secondary cameras from their cosines (cos1 >= cos2)
    and the threshold ``d_bnd`` > 0. (1, 0) in a one-camera region; they always sum to 1."""
    d12 = cos1 - cos2
    if d12 >= d_bnd:
        return 1.0, 0.0
    w1 = 0.5 * (1.0 + d12 / d_bnd)
    return w1, 1.0 - w1


@njit(cache=True)
def ulr_weights(theta: np.ndarray, m: int, k: int, out: np.ndarray) -> int:
    """ULR weights for the ``m`` visible cameras whose angles ``theta[:m]`` (radians) are sorted
    ascending; writes normalised weights of the first ``n`` cameras into ``out[:n]`` and returns ``n``.

    The threshold is ``theta[k]`` (the (k+1)-th nearest) when there are more than k cameras, else the
    farthest available one, so at most k cameras are blended. When all candidate angles are equal the
    blended cameras share the weight equally.
    """
    if m <= 0:
        return 0
    if m == 1:
        out[0] = 1.0
        return 1
    th = theta[k] if m > k else theta[m - 1]
    n = k if m > k else m
    total = 0.0
    for i in range(n):
        w = 1.0 - theta[i] / th if th > 0 else 0.0
        w = w if w > 0 else 0.0
        out[i] = w
        total += w
    if total <= 0:
        for i in range(n):
            out[i] = 1.0 / n
        return n
    for i in range(n):
        out[i] /= total
    return n


def suggest_d_bnd(neighbour_angle_rad: float, blend_fraction: float = 0.5) -> float:
    """A D_bnd that blends over ``blend_fraction`` of the way between two cameras ``neighbour_angle_rad``
    apart (seen from the surface). With the virtual ray at angle phi from camera 1, D12 ~ delta
    (delta - 2 phi) / 2, so the two-camera band is ``2 D_bnd / delta`` wide: D_bnd = f delta^2 / 2."""
    if not neighbour_angle_rad > 0 or not 0 < blend_fraction <= 1:
        raise ValueError("need neighbour_angle_rad > 0 and 0 < blend_fraction <= 1")
    return blend_fraction * neighbour_angle_rad**2 / 2


def neighbour_angle(centers: np.ndarray, point: np.ndarray) -> float:
    """Median over cameras of the angle (radians) to the nearest other camera, seen from ``point``
    (3,): the camera spacing that :func:`suggest_d_bnd` needs. centers (N, 3), N >= 2. Cameras at the
    same place (angle below 1e-6 rad, about arccos's resolution: a duplicated pose) tell nothing of the
    spacing and are not each other's neighbours; 0.0 when no camera has a neighbour at another place."""
    d = np.asarray(centers, np.float64) - np.asarray(point, np.float64)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ang = np.arccos(np.clip(d @ d.T, -1.0, 1.0))
    np.fill_diagonal(ang, np.inf)
    ang[ang < 1e-6] = np.inf  # coincident cameras
    nearest = ang.min(axis=1)
    nearest = nearest[np.isfinite(nearest)]
    return float(np.median(nearest)) if nearest.size else 0.0


def global_camera(axes: np.ndarray, virtual_axis: np.ndarray) -> int:
    """Index of the camera whose optical axis (rows of ``axes`` (N, 3), unit) is closest to
    ``virtual_axis`` (3,): the single source camera of the ``global`` method."""
    return int(np.argmax(np.asarray(axes) @ np.asarray(virtual_axis)))
