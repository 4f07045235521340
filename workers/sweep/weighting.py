"""The five colour weightings, as small compiled functions shared by the renderer's kernel and tests.

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
  ``C = 1/2 (1 + D12/D_bnd) C1 + 1/2 (1 - D12/D_bnd) C2``; :func:`kojima_weights`.
- ``kojima_k``: the paper's announced next step (section V: "use more than two cameras for
  appropriate boundary blending"): every camera whose cosine is within ``D_bnd`` of the primary's
  takes part; :func:`kojima_k_weights`. Derivation below.

k-camera boundary blending (``kojima_k``)
-----------------------------------------
Notation of the paper: for a virtual pixel p_v, the cameras i = 1..m that see its surface point
have angles theta_i to the virtual ray; camera 1, the primary, has the largest cosine. Generalise
eq. (1) to every camera::

    D_1i = cos th_1 - cos th_i >= 0                                       (1k)

(D_11 = 0, D_12 is eq. (1)). In a two-camera region eq. (6) gives the secondary a weight relative
to the primary's of::

    w_2 / w_1 = (1 - D12/D_bnd) / (1 + D12/D_bnd) = (D_bnd - D12) / (D_bnd + D12)

so define, for a cosine deficit D >= 0, the relative weight ::

    rho(D) = (D_bnd - D) / (D_bnd + D)   for D < D_bnd,     rho(D) = 0   for D >= D_bnd   (6a)

(rho(0) = 1, rho falls monotonically and reaches 0 at D = D_bnd). The k-camera rule keeps, for every
camera, the ratio to the primary that eq. (6) gives that pair, w_i / w_1 = rho(D_1i), and makes the
weights sum to 1::

    w_i = rho(D_1i) / sum_j rho(D_1j),        C_v = sum_i w_i C_i                        (6k)

The cameras blended are S = {i : D_1i < D_bnd} (eq. (4) for each camera); eq. (2) for each
camera (D_1i >= D_bnd) gives it weight 0. Properties:

- Reduction to eq. (6). With S = {1, 2}: sum = 1 + rho(D12) = 2 D_bnd / (D_bnd + D12), so
  w_1 = (D_bnd + D12) / (2 D_bnd) = 1/2 (1 + D12/D_bnd) and w_2 = 1/2 (1 - D12/D_bnd): eq. (6)
  (and eq. (5)). With S = {1}: w_1 = 1, eq. (3).
- One-camera regions stay one-camera. The secondary has the second largest cosine, so
  D12 >= D_bnd (eq. (2)) implies D_1i >= D_bnd for every i != 1: S = {1}, C_v = C_1, no blur.
  Where exactly two cameras are within D_bnd (the paper's two-camera regions) the colour is
  eq. (5)'s; only where three or more are, around the junctions of three or more one-camera regions,
  does it differ from ``kojima``.
- Continuity. (6k) depends on the cameras only through D_1i = max_j cos th_j - cos th_i: the
  maximum is continuous, rho is continuous on [0, inf) (including at D_bnd, where it reaches 0) and
  the denominator is >= rho(0) = 1. No rank enters, so nothing jumps when the primary changes (at a
  swap both cosines are the maximum: D = 0, rho = 1, equal weights), when the secondary changes
  (weights depend on D, not on rank) or when the set S changes (a camera enters or leaves at
  D = D_bnd with weight rho = 0). Two-camera ``kojima`` is discontinuous exactly where a third camera
  overtakes the secondary inside a two-camera region: the weight w_2 jumps from camera 2 to camera 3.
- Lipschitz bound (what the tests check on a fine viewpoint sweep): |rho'(D)| = 2 D_bnd / (D_bnd + D)^2
  <= 2 / D_bnd and |Delta D_1i| <= 2 max_j |Delta cos th_j|, and with sums >= 1,
  sum_i |Delta w_i| <= 2 sum_i |Delta rho_i|, hence
  ``sum_i |Delta w_i| <= 8 n max_j |Delta cos th_j| / D_bnd`` for n cameras: the weight change per
  step shrinks with the step.
- Symmetry: equal cosines get equal weights (three cameras at one angle: 1/3 each); weights lie in
  [0, 1] and the primary's is the largest.
"""
from __future__ import annotations

import numpy as np
from numba import njit

METHODS = ("global", "nearest", "ulr", "kojima", "kojima_k")
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
def kojima_k_weights(cosines: np.ndarray, m: int, d_bnd: float, out: np.ndarray) -> int:
    """Eq. (6k) of the module docstring: weights of the ``m`` cameras whose cosines are
    ``cosines[:m]`` (any order; float64, cosines of the angles between each camera's ray and the
    virtual ray) with the threshold ``d_bnd`` > 0 (a cosine difference, dimensionless). Writes
    ``out[:m]`` (float64, in the order of ``cosines``; 0 for cameras whose cosine is ``d_bnd`` or more
    below the largest) and returns how many are non-zero (>= 1 when m >= 1). The weights sum to 1.
    Allocates nothing: the renderer calls it per pixel."""
    if m <= 0:
        return 0
    cmax = cosines[0]
    for i in range(1, m):
        if cosines[i] > cmax:
            cmax = cosines[i]
    total = 0.0
    n = 0
    for i in range(m):
        d = cmax - cosines[i]  # D_1i, eq. (1k)
        r = (d_bnd - d) / (d_bnd + d) if d < d_bnd else 0.0  # rho(D_1i), eq. (6a)
        out[i] = r
        total += r
        if r > 0.0:
            n += 1
    for i in range(m):  # total >= rho(0) = 1
        out[i] /= total
    return n


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
