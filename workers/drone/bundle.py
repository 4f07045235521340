"""Bundle adjustment (the paper's eq. 5): Levenberg–Marquardt over all cameras and points.

Minimises ``0.5 * sum_i rho(|r_i|^2)`` where ``r_i`` is the reprojection residual (pixels) of
observation ``i`` and ``rho`` a robust loss (trivial, Huber or Cauchy, applied by iteratively
re-weighted least squares). Each LM step solves the damped normal equations

    [U + mu D_U   W          ] [dc]   [-g_c]
    [W^T          V + mu D_V ] [dp] = [-g_p]

by eliminating the points (3x3 blocks ``V``) first: the reduced camera system
``S = U - W V^-1 W^T`` is assembled from camera-pair blocks as a ``scipy.sparse`` matrix and
factorised (dense Cholesky while small, sparse LU beyond), then the point steps follow by back
substitution. ``D`` is the clamped diagonal of ``J^T J`` and ``mu = 1 / radius`` follows the
trust-region rule of Ceres' LM strategy (Nielsen's update), except that a step achieving more than
half the predicted decrease grows the radius 4x. Fixed camera parameters (the gauge:
the first camera's pose) are removed from the reduced system.

Self-calibration: a model with parameters *shared* by every camera (``n_shared`` > 0, e.g. one focal
length and radial distortion, :class:`~workers.drone.camera_models.RadialModel`) adds a small block
``dg`` to the reduced system, bordering it::

    [S_cc    S_cg] [dc]   [r_c]
    [S_cg^T  S_gg] [dg] = [r_g]

solved with the factorisation of ``S_cc`` (a few more right-hand sides) and the ``g x g`` Schur
complement of the border. Priors enter as extra squared residuals: a Gaussian prior on the shared
parameters (:class:`SharedPrior`: what holds the focal length where the images cannot, e.g. a flat
scene seen from straight above) and one on camera centres (:class:`CentrePrior`: GPS positions).

Jacobians come from the analytic camera models in :mod:`workers.drone.camera_models`; the heavy
loops are numba kernels (``cache=True``).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Literal

import numba
import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numba import njit, prange
from threadpoolctl import threadpool_limits

from .camera_models import CameraModel, poses_from_params

LossName = Literal["trivial", "huber", "cauchy"]
_MIN_DIAG = 1e-6
_MAX_DIAG = 1e32
_PARALLEL_MIN_OBS = 100_000
_RADIUS_GROWTH = 4.0  # trust-region growth after a step whose cost fell by more than half the predicted


@dataclass(frozen=True)
class BAOptions:
    """Solver settings; defaults follow Ceres' LM defaults where they exist."""

    max_iterations: int = 100
    """Counts every linear solve, accepted or not (as Ceres does)."""
    function_tolerance: float = 1e-6
    """Stop when an accepted step changes the cost by less than this fraction."""
    gradient_tolerance: float = 1e-10
    """Stop when max |gradient| <= this times the first iteration's max |gradient|."""
    parameter_tolerance: float = 1e-8
    initial_radius: float = 1e4
    loss: LossName = "trivial"
    loss_scale: float = 1.0
    """Pixels: where the robust loss starts to down-weight a residual."""
    dense_limit: int = 2000
    """Reduced systems up to this many unknowns are factorised densely."""
    max_invalid_steps: int = 10


@dataclass
class BAResult:
    """Outcome of :func:`solve`. ``params`` (C, p) and ``points`` (P, 3) are new arrays."""

    params: np.ndarray
    points: np.ndarray
    initial_cost: float
    final_cost: float
    iterations: int
    accepted: int
    termination: str
    seconds: float
    history: list[float] = field(default_factory=list)
    """Cost after every accepted step."""
    shared: np.ndarray | None = None
    """The refined shared parameters (n_shared,) of a self-calibrating model, else None."""


@dataclass(frozen=True)
class SharedPrior:
    """Gaussian prior on the shared parameters: cost ``0.5 * sum(((g - mean) / sigma)^2)``;
    mean, sigma (n_shared,) float64 in the parameters' units (``sigma`` inf: no prior on that one)."""

    mean: np.ndarray
    sigma: np.ndarray


@dataclass(frozen=True)
class CentrePrior:
    """Prior on camera centres ``C = -R^T t``: cost ``0.5 * sum |(C_i - target_i) / sigma_i|^2``;
    target (C, 3) world units, sigma (C,) world units (inf: no prior on that camera)."""

    target: np.ndarray
    sigma: np.ndarray


# ---------------------------------------------------------------------------------------------
# Robust losses (IRLS): cost rho(s) and weight rho'(s) of the squared residual norm s.
# ---------------------------------------------------------------------------------------------
def loss_cost_and_weight(s: np.ndarray, loss: LossName, scale: float) -> tuple[float, np.ndarray]:
    """Total cost ``0.5 * sum rho(s)`` and per-observation weights ``rho'(s)``, s (N,) px^2."""
    if loss == "trivial":
        return 0.5 * float(s.sum()), np.ones_like(s)
    c2 = scale * scale
    if loss == "huber":
        root = np.sqrt(s)
        inlier = s <= c2
        rho = np.where(inlier, s, 2.0 * scale * root - c2)
        w = np.where(inlier, 1.0, scale / np.maximum(root, 1e-300))
        return 0.5 * float(rho.sum()), w
    if loss == "cauchy":
        return 0.5 * float((c2 * np.log1p(s / c2)).sum()), 1.0 / (1.0 + s / c2)
    raise ValueError(f"unknown loss {loss!r}")


# ---------------------------------------------------------------------------------------------
# Problem structure (depends only on which camera sees which point)
# ---------------------------------------------------------------------------------------------
@dataclass
class _Structure:
    order: np.ndarray          # (N,) observations sorted by point
    point_start: np.ndarray    # (P + 1,) ranges into order
    blk_indptr: np.ndarray     # CSR (upper triangle incl. diagonal) of co-visible camera pairs
    blk_indices: np.ndarray
    rows: np.ndarray           # assembled entries (free unknowns only): row, col
    cols: np.ndarray
    take: np.ndarray           # indices into the flattened block data
    flat: np.ndarray           # rows * n_free + cols: the entries' positions in the dense reduced matrix
    free_index: np.ndarray     # (C * p,) position among free unknowns, -1 when fixed
    n_free: int
    pair_block: np.ndarray     # per point, per ordered pair of its observations: block id, -1 if below the diagonal
    pair_start: np.ndarray     # (P + 1,) ranges into pair_block


def _structure(n_cams: int, n_pts: int, p: int, cam_idx: np.ndarray, pt_idx: np.ndarray,
               fixed: np.ndarray) -> _Structure:
    order = np.argsort(pt_idx, kind="stable")
    counts = np.bincount(pt_idx, minlength=n_pts)
    point_start = np.concatenate([[0], np.cumsum(counts)])
    vis = sp.csr_matrix((np.ones(len(cam_idx)), (pt_idx, cam_idx)), shape=(n_pts, n_cams))
    cov = sp.triu((vis.T @ vis).tocsr() + sp.identity(n_cams, format="csr")).tocsr()
    cov.sort_indices()
    blk_rows = np.repeat(np.arange(n_cams), np.diff(cov.indptr))
    blk_cols = cov.indices
    n_blk = len(blk_cols)
    # Entries of every block, then the transposes of the off-diagonal blocks.
    ii, jj = np.meshgrid(np.arange(p), np.arange(p), indexing="ij")
    r_all = (blk_rows[:, None, None] * p + ii).ravel()
    c_all = (blk_cols[:, None, None] * p + jj).ravel()
    off = np.flatnonzero(blk_rows != blk_cols)
    # Transposed block: entry (i, j) of block (a, b) lands at row b*p + j, col a*p + i.
    r_t = (blk_cols[off, None, None] * p + jj).ravel()
    c_t = (blk_rows[off, None, None] * p + ii).ravel()
    rows = np.concatenate([r_all, r_t])
    cols = np.concatenate([c_all, c_t])
    free_index = np.full(n_cams * p, -1, np.int64)
    free_flat = ~fixed.ravel()
    free_index[free_flat] = np.arange(int(free_flat.sum()))
    keep = (free_index[rows] >= 0) & (free_index[cols] >= 0)
    n_free = int(free_flat.sum())
    free_rows, free_cols = free_index[rows[keep]], free_index[cols[keep]]
    counts = counts.astype(np.int64)
    pair_start = np.concatenate([[0], np.cumsum(counts * counts)]).astype(np.int64)
    indptr, indices = cov.indptr.astype(np.int64), blk_cols.astype(np.int64)
    pair_block = _pair_blocks(cam_idx.astype(np.int64), order.astype(np.int64), point_start.astype(np.int64),
                              pair_start, indptr, indices)
    return _Structure(
        order=order.astype(np.int64), point_start=point_start.astype(np.int64),
        blk_indptr=cov.indptr.astype(np.int64), blk_indices=blk_cols.astype(np.int64),
        rows=free_rows, cols=free_cols, flat=free_rows * n_free + free_cols,
        take=np.concatenate([np.arange(n_blk * p * p), _transposed_take(off, p)])[keep],
        free_index=free_index, n_free=n_free, pair_block=pair_block, pair_start=pair_start,
    )


def _transposed_take(off: np.ndarray, p: int) -> np.ndarray:
    """Flat indices into ``blocks`` (B, p, p) that read block ``off`` entries in (i, j) order.

    Paired with rows ``b*p + j`` / cols ``a*p + i`` this writes the transpose of each block.
    """
    ii, jj = np.meshgrid(np.arange(p), np.arange(p), indexing="ij")
    return (off[:, None, None] * p * p + ii * p + jj).ravel()


# ---------------------------------------------------------------------------------------------
# Numba kernels
# ---------------------------------------------------------------------------------------------
@njit(cache=True, fastmath=True)
def _normal_blocks(Jc, Jp, r, ci, pj, n_cams, n_pts):
    """U (C,p,p), V (P,3,3), W (N,3,p) = Jp^T Jc, gc (C,p), gp (P,3) from weighted r, Jc, Jp."""
    n, _, p = Jc.shape
    U = np.zeros((n_cams, p, p))
    V = np.zeros((n_pts, 3, 3))
    W = np.empty((n, 3, p))
    gc = np.zeros((n_cams, p))
    gp = np.zeros((n_pts, 3))
    for o in range(n):
        c = ci[o]
        q = pj[o]
        for a in range(p):
            ja0 = Jc[o, 0, a]
            ja1 = Jc[o, 1, a]
            gc[c, a] += ja0 * r[o, 0] + ja1 * r[o, 1]
            for b in range(a, p):
                U[c, a, b] += ja0 * Jc[o, 0, b] + ja1 * Jc[o, 1, b]
            for b in range(3):
                W[o, b, a] = ja0 * Jp[o, 0, b] + ja1 * Jp[o, 1, b]
        for a in range(3):
            gp[q, a] += Jp[o, 0, a] * r[o, 0] + Jp[o, 1, a] * r[o, 1]
            for b in range(a, 3):
                V[q, a, b] += Jp[o, 0, a] * Jp[o, 0, b] + Jp[o, 1, a] * Jp[o, 1, b]
    for c in range(n_cams):
        for a in range(p):
            for b in range(a):
                U[c, a, b] = U[c, b, a]
    for q in range(n_pts):
        for a in range(3):
            for b in range(a):
                V[q, a, b] = V[q, b, a]
    return U, V, W, gc, gp


@njit(cache=True, inline="always")
def _clamped(x):
    return min(max(x, _MIN_DIAG), _MAX_DIAG)


@njit(cache=True)
def _inverse3(A):
    a, b, c = A[0, 0], A[0, 1], A[0, 2]
    d, e, f = A[1, 0], A[1, 1], A[1, 2]
    g, h, k = A[2, 0], A[2, 1], A[2, 2]
    c00 = e * k - f * h
    c01 = -(d * k - f * g)
    c02 = d * h - e * g
    det = a * c00 + b * c01 + c * c02
    out = np.empty((3, 3))
    if det == 0.0:
        out[:] = np.nan
        return out
    inv = 1.0 / det
    out[0, 0] = c00 * inv
    out[1, 0] = c01 * inv
    out[2, 0] = c02 * inv
    out[0, 1] = -(b * k - c * h) * inv
    out[1, 1] = (a * k - c * g) * inv
    out[2, 1] = -(a * h - b * g) * inv
    out[0, 2] = (b * f - c * e) * inv
    out[1, 2] = -(a * f - c * d) * inv
    out[2, 2] = (a * e - b * d) * inv
    return out


@njit(cache=True)
def _block_id(indptr, indices, a, b):
    lo = indptr[a]
    hi = indptr[a + 1]
    while lo < hi:
        mid = (lo + hi) // 2
        if indices[mid] < b:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True)
def _pair_blocks(ci, order, point_start, pair_start, blk_indptr, blk_indices):
    """For every point and ordered pair (a, b) of its observations, the reduced-system block of
    cameras (ca, cb) when ca <= cb, else -1 (the transpose is written by its mirror pair)."""
    out = np.empty(pair_start[-1], np.int64)
    for q in range(point_start.shape[0] - 1):
        s0 = point_start[q]
        m = point_start[q + 1] - s0
        k = pair_start[q]
        for ia in range(m):
            ca = ci[order[s0 + ia]]
            for ib in range(m):
                cb = ci[order[s0 + ib]]
                out[k] = _block_id(blk_indptr, blk_indices, ca, cb) if ca <= cb else -1
                k += 1
    return out


@njit(cache=True, inline="always", fastmath=True)
def _subtract_outer(S, blk, Y, ia, W, ob, p):
    """S[blk] -= Y[ia] W[ob] (p x 3 times 3 x p); ``p`` a constant at the call sites unrolls it."""
    for a in range(p):
        y0 = Y[ia, a, 0]
        y1 = Y[ia, a, 1]
        y2 = Y[ia, a, 2]
        for b in range(p):
            S[blk, a, b] -= y0 * W[ob, 0, b] + y1 * W[ob, 1, b] + y2 * W[ob, 2, b]


@njit(parallel=True, cache=True, fastmath=True)
def _schur(U, V, W, gc, gp, ci, order, point_start, pair_block, pair_start, blk_indptr, blk_indices, mu,
           n_chunks):
    """Damped reduced camera system: blocks (B,p,p) upper, rhs (C,p), Vinv (P,3,3)."""
    n_cams, p, _ = U.shape
    n_pts = V.shape[0]
    n_blk = blk_indices.shape[0]
    S_parts = np.zeros((n_chunks, n_blk, p, p))
    b_parts = np.zeros((n_chunks, n_cams, p))
    Vinv = np.empty((n_pts, 3, 3))
    for k in prange(n_chunks):
        lo = n_pts * k // n_chunks
        hi = n_pts * (k + 1) // n_chunks
        S = S_parts[k]
        rhs = b_parts[k]
        Y = np.empty((64, p, 3))
        for q in range(lo, hi):
            Vd = V[q].copy()
            for a in range(3):
                Vd[a, a] += mu * _clamped(V[q, a, a])
            Vi = _inverse3(Vd)
            Vinv[q] = Vi
            s0 = point_start[q]
            m = point_start[q + 1] - s0
            if m > Y.shape[0]:
                Y = np.empty((m, p, 3))
            # Y_a = W_a V^-1 (p x 3); rhs_c += Y_a g_p (the sign is applied once at the end)
            for ia in range(m):
                o = order[s0 + ia]
                for a in range(p):
                    for b in range(3):
                        Y[ia, a, b] = W[o, 0, a] * Vi[0, b] + W[o, 1, a] * Vi[1, b] + W[o, 2, a] * Vi[2, b]
                c = ci[o]
                for a in range(p):
                    rhs[c, a] += Y[ia, a, 0] * gp[q, 0] + Y[ia, a, 1] * gp[q, 1] + Y[ia, a, 2] * gp[q, 2]
            # S_ab -= Y_a W_b^T for every ordered pair with ca <= cb (both orders when ca == cb).
            pk = pair_start[q]
            for ia in range(m):
                for ib in range(m):
                    blk = pair_block[pk]
                    pk += 1
                    if blk < 0:
                        continue
                    ob = order[s0 + ib]
                    if p == 9:
                        _subtract_outer(S, blk, Y, ia, W, ob, 9)
                    elif p == 6:
                        _subtract_outer(S, blk, Y, ia, W, ob, 6)
                    else:
                        _subtract_outer(S, blk, Y, ia, W, ob, p)
    S = S_parts.sum(axis=0)
    rhs = b_parts.sum(axis=0)
    for c in range(n_cams):
        blk = _block_id(blk_indptr, blk_indices, c, c)
        for a in range(p):
            for b in range(p):
                S[blk, a, b] += U[c, a, b]
            S[blk, a, a] += mu * _clamped(U[c, a, a])
            rhs[c, a] = rhs[c, a] - gc[c, a]
    return S, rhs, Vinv


@njit(parallel=True, cache=True)
def _back_substitute(dc, W, Vinv, gp, ci, order, point_start):
    """Point steps dp (P,3) = V^-1 (-g_p - sum_a W_a^T dc_a)."""
    n_pts = Vinv.shape[0]
    p = W.shape[2]
    dp = np.empty((n_pts, 3))
    for q in prange(n_pts):
        t0 = -gp[q, 0]
        t1 = -gp[q, 1]
        t2 = -gp[q, 2]
        for k in range(point_start[q], point_start[q + 1]):
            o = order[k]
            c = ci[o]
            for a in range(p):
                d = dc[c, a]
                t0 -= W[o, 0, a] * d
                t1 -= W[o, 1, a] * d
                t2 -= W[o, 2, a] * d
        for a in range(3):
            dp[q, a] = Vinv[q, a, 0] * t0 + Vinv[q, a, 1] * t1 + Vinv[q, a, 2] * t2
    return dp


@njit(parallel=True, cache=True)
def _model_decrease(Jc, Jp, r, dc, dp, ci, pj):
    """Decrease of the linearised cost 0.5|r + J d|^2 for the step d."""
    total = 0.0
    p = Jc.shape[2]
    for o in prange(ci.shape[0]):
        c = ci[o]
        q = pj[o]
        for k in range(2):
            jd = Jp[o, k, 0] * dp[q, 0] + Jp[o, k, 1] * dp[q, 1] + Jp[o, k, 2] * dp[q, 2]
            for a in range(p):
                jd += Jc[o, k, a] * dc[c, a]
            total += -r[o, k] * jd - 0.5 * jd * jd
    return total


@njit(cache=True, fastmath=True)
def _shared_blocks(Jc, Jp, Jg, r, ci, pj, n_cams, n_pts):
    """The shared parameters' blocks: H (C,p,g) = Jc^T Jg per camera, G (g,g) = Jg^T Jg,
    Wg (P,3,g) = Jp^T Jg per point, gg (g,) = Jg^T r (weighted inputs, as :func:`_normal_blocks`)."""
    n, _, p = Jc.shape
    g = Jg.shape[2]
    H = np.zeros((n_cams, p, g))
    G = np.zeros((g, g))
    Wg = np.zeros((n_pts, 3, g))
    gg = np.zeros(g)
    for o in range(n):
        c = ci[o]
        q = pj[o]
        for a in range(g):
            j0 = Jg[o, 0, a]
            j1 = Jg[o, 1, a]
            gg[a] += j0 * r[o, 0] + j1 * r[o, 1]
            for b in range(g):
                G[a, b] += j0 * Jg[o, 0, b] + j1 * Jg[o, 1, b]
            for b in range(p):
                H[c, b, a] += Jc[o, 0, b] * j0 + Jc[o, 1, b] * j1
            for b in range(3):
                Wg[q, b, a] += Jp[o, 0, b] * j0 + Jp[o, 1, b] * j1
    return H, G, Wg, gg


@njit(cache=True, fastmath=True)
def _shared_schur(W, Vinv, Wg, gp, ci, order, point_start, n_cams):
    """What eliminating the points takes from the border: sum_q W_q^T V_q^-1 Wg_q per camera
    (C,p,g), sum_q Wg_q^T V_q^-1 Wg_q (g,g) and sum_q Wg_q^T V_q^-1 g_q (g,)."""
    p = W.shape[2]
    g = Wg.shape[2]
    n_pts = Vinv.shape[0]
    Scg = np.zeros((n_cams, p, g))
    Sgg = np.zeros((g, g))
    rg = np.zeros(g)
    Z = np.empty((3, g))
    for q in range(n_pts):
        for k in range(3):
            for b in range(g):
                Z[k, b] = Vinv[q, k, 0] * Wg[q, 0, b] + Vinv[q, k, 1] * Wg[q, 1, b] + Vinv[q, k, 2] * Wg[q, 2, b]
        for a in range(g):
            rg[a] += Z[0, a] * gp[q, 0] + Z[1, a] * gp[q, 1] + Z[2, a] * gp[q, 2]
            for b in range(g):
                Sgg[a, b] += Wg[q, 0, a] * Z[0, b] + Wg[q, 1, a] * Z[1, b] + Wg[q, 2, a] * Z[2, b]
        for k in range(point_start[q], point_start[q + 1]):
            o = order[k]
            c = ci[o]
            for a in range(p):
                for b in range(g):
                    Scg[c, a, b] += W[o, 0, a] * Z[0, b] + W[o, 1, a] * Z[1, b] + W[o, 2, a] * Z[2, b]
    return Scg, Sgg, rg


@njit(parallel=True, cache=True)
def _model_decrease_shared(Jc, Jp, Jg, r, dc, dp, dg, ci, pj):
    """:func:`_model_decrease` with the shared parameters' step dg (g,) too."""
    total = 0.0
    p = Jc.shape[2]
    g = Jg.shape[2]
    for o in prange(ci.shape[0]):
        c = ci[o]
        q = pj[o]
        for k in range(2):
            jd = Jp[o, k, 0] * dp[q, 0] + Jp[o, k, 1] * dp[q, 1] + Jp[o, k, 2] * dp[q, 2]
            for a in range(p):
                jd += Jc[o, k, a] * dc[c, a]
            for a in range(g):
                jd += Jg[o, k, a] * dg[a]
            total += -r[o, k] * jd - 0.5 * jd * jd
    return total


# ---------------------------------------------------------------------------------------------
# The solver
# ---------------------------------------------------------------------------------------------
def _factorise(struct: _Structure, blocks: np.ndarray, dense_limit: int) -> Callable[[np.ndarray], np.ndarray] | None:
    """A solver ``b (n,) or (n, k) -> S^-1 b`` for the reduced matrix on the free unknowns; None when
    S is not positive definite."""
    n = struct.n_free
    values = blocks.ravel()[struct.take]
    try:
        if n <= dense_limit:  # every (row, col) appears once: written straight into the dense matrix
            dense = np.zeros((n, n))
            dense.ravel()[struct.flat] = values
            factor = scipy.linalg.cho_factor(dense, overwrite_a=True, check_finite=False)
            return lambda b: scipy.linalg.cho_solve(factor, b, check_finite=False)
        S = sp.coo_matrix((values, (struct.rows, struct.cols)), shape=(n, n))
        lu = spla.splu(S.tocsc(), permc_spec="MMD_AT_PLUS_A")
        return lu.solve
    except (np.linalg.LinAlgError, RuntimeError):
        return None


def _solve_reduced(struct: _Structure, blocks: np.ndarray, rhs: np.ndarray, dense_limit: int
                   ) -> np.ndarray | None:
    """Solve S x = rhs on the free unknowns; None when S is not positive definite."""
    if struct.n_free == 0:
        return np.zeros(0)
    solve_s = _factorise(struct, blocks, dense_limit)
    if solve_s is None:
        return None
    x = solve_s(rhs.ravel()[struct.free_index >= 0])
    return x if np.all(np.isfinite(x)) else None


def _solve_bordered(struct: _Structure, blocks: np.ndarray, rhs: np.ndarray, border: np.ndarray, corner: np.ndarray,
                    rhs_g: np.ndarray, dense_limit: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Solve ``[[S, B], [B^T, D]] [x; y] = [rhs; rhs_g]``: S the reduced camera matrix (free unknowns),
    border B (C * p, g) (all camera unknowns), corner D (g, g). Returns x (free,), y (g,); None when the
    system is not positive definite."""
    keep = struct.free_index >= 0
    B = border[keep]
    b = rhs.ravel()[keep]
    try:
        if struct.n_free == 0:
            y = np.linalg.solve(corner, rhs_g)
            return np.zeros(0), y
        solve_s = _factorise(struct, blocks, dense_limit)
        if solve_s is None:
            return None
        Z = solve_s(np.column_stack([b, B]))
        z, Y = Z[:, 0], Z[:, 1:]
        reduced = corner - B.T @ Y
        y = scipy.linalg.cho_solve(scipy.linalg.cho_factor(reduced, check_finite=False), rhs_g - B.T @ z,
                                   check_finite=False)
    except (np.linalg.LinAlgError, RuntimeError, ValueError):
        return None
    x = z - Y @ y
    return (x, y) if np.all(np.isfinite(x)) and np.all(np.isfinite(y)) else None


def solve(
    model: CameraModel,
    params: np.ndarray,
    points: np.ndarray,
    cam_idx: np.ndarray,
    pt_idx: np.ndarray,
    obs: np.ndarray,
    fixed: np.ndarray | None = None,
    options: BAOptions = BAOptions(),
    callback: Callable[[int, float], None] | None = None,
    *,
    shared: np.ndarray | None = None,
    shared_fixed: np.ndarray | None = None,
    shared_prior: SharedPrior | None = None,
    centre_prior: CentrePrior | None = None,
) -> BAResult:
    """Levenberg–Marquardt bundle adjustment.

    params: (C, p) float64 camera parameters of ``model``; points: (P, 3) float64;
    cam_idx, pt_idx: (N,) int indices of each observation; obs: (N, 2) float64 pixels;
    fixed: (C, p) bool, True for parameters held constant (default: the first camera's pose).
    ``callback(iteration, cost)`` is called after every linear solve.
    Points seen by no observation keep their values.
    A model with shared parameters (``model.n_shared`` > 0) needs their start values ``shared``
    (n_shared,); ``shared_fixed`` (n_shared,) bool holds some constant; the result's ``shared`` holds
    the refined values. ``shared_prior`` and ``centre_prior`` add the priors described by their classes
    (the cost then includes them).
    """
    t0 = time.perf_counter()
    g = int(getattr(model, "n_shared", 0))
    if g and shared is None:
        raise ValueError("this camera model has shared parameters: give their start values (shared=...)")
    prob = _Problem(model, np.ascontiguousarray(cam_idx, np.int64), np.ascontiguousarray(pt_idx, np.int64),
                    np.ascontiguousarray(obs, np.float64), options, shared_prior, centre_prior)
    params = np.ascontiguousarray(params, np.float64)
    if fixed is None:
        fixed = np.zeros(params.shape, bool)
        fixed[0, :6] = True
    shared = np.ascontiguousarray(shared, np.float64).reshape(g) if g else np.zeros(0)
    shared_free = (np.ones(g, bool) if shared_fixed is None else ~np.asarray(shared_fixed, bool).reshape(g))
    # Threads only pay off on large problems; on small ones (and on a busy machine) the
    # synchronisation of numba's and BLAS's thread pools costs more than it saves.
    threads = numba.get_num_threads() if len(prob.ci) >= _PARALLEL_MIN_OBS else 1
    previous = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        with threadpool_limits(1, user_api="blas"):
            result = _levenberg_marquardt(prob, params, np.ascontiguousarray(points, np.float64), shared, fixed,
                                          shared_free, threads, callback)
    finally:
        numba.set_num_threads(previous)
    result.seconds = time.perf_counter() - t0
    return result


@dataclass
class _Evaluation:
    """Cost and linearisation at one point: IRLS weights w (N,), residuals r (N, 2), Jacobians Jc, Jp,
    Jg (None without shared parameters); the priors' residuals and Jacobians (None when absent):
    shared e_g (g,) with its diagonal Jacobian d_g (g,), centres e_c (C, 3) and J_c (C, 3, p)."""

    cost: float
    w: np.ndarray
    r: np.ndarray
    Jc: np.ndarray
    Jp: np.ndarray
    Jg: np.ndarray | None
    e_g: np.ndarray | None = None
    d_g: np.ndarray | None = None
    e_c: np.ndarray | None = None
    J_c: np.ndarray | None = None


@dataclass
class _Problem:
    model: CameraModel
    ci: np.ndarray
    pj: np.ndarray
    obs: np.ndarray
    options: BAOptions
    shared_prior: SharedPrior | None = None
    centre_prior: CentrePrior | None = None

    def evaluate(self, params: np.ndarray, points: np.ndarray, shared: np.ndarray) -> _Evaluation:
        """Robust cost (priors included), IRLS weights, residuals, Jacobians."""
        if len(shared):
            r, Jc, Jp, Jg = self.model.evaluate_shared(params, shared, points, self.ci, self.pj, self.obs, True)
        else:
            (r, Jc, Jp), Jg = self.model.evaluate(params, points, self.ci, self.pj, self.obs, True), None
        cost, w = loss_cost_and_weight(np.einsum("ij,ij->i", r, r), self.options.loss, self.options.loss_scale)
        ev = _Evaluation(cost, w, r, Jc, Jp, Jg)
        if self.shared_prior is not None and len(shared):
            inv = 1.0 / np.asarray(self.shared_prior.sigma, np.float64)
            ev.e_g = (shared - self.shared_prior.mean) * inv
            ev.d_g = inv
            ev.cost += 0.5 * float(ev.e_g @ ev.e_g)
        if self.centre_prior is not None:
            ev.e_c, ev.J_c = _centre_residuals(params, self.centre_prior)
            ev.cost += 0.5 * float((ev.e_c * ev.e_c).sum())
        return ev


def _centre_residuals(params: np.ndarray, prior: CentrePrior) -> tuple[np.ndarray, np.ndarray]:
    """Whitened centre residuals (C, 3) and their Jacobians (C, 3, p) by the camera parameters: with
    ``R <- exp([d]x) R``, ``C = -R^T t`` moves by ``-R^T [t]x d`` and by ``-R^T dt``."""
    R, t = poses_from_params(params)
    inv = np.where(np.isfinite(prior.sigma), 1.0 / np.asarray(prior.sigma, np.float64), 0.0)
    C = -np.einsum("nji,nj->ni", R, t)
    e = (C - np.nan_to_num(prior.target)) * inv[:, None]
    tx = np.zeros((len(t), 3, 3))
    tx[:, 0, 1], tx[:, 0, 2], tx[:, 1, 2] = -t[:, 2], t[:, 1], -t[:, 0]
    tx[:, 1, 0], tx[:, 2, 0], tx[:, 2, 1] = t[:, 2], -t[:, 1], t[:, 0]
    Rt = np.swapaxes(R, 1, 2)
    J = np.zeros((len(t), 3, params.shape[1]))
    J[:, :, :3] = -Rt @ tx
    J[:, :, 3:6] = -Rt
    return e, J * inv[:, None, None]


def _levenberg_marquardt(prob: _Problem, params: np.ndarray, points: np.ndarray, shared: np.ndarray,
                         fixed: np.ndarray, shared_free: np.ndarray, threads: int,
                         callback: Callable[[int, float], None] | None) -> BAResult:
    options = prob.options
    ci, pj = prob.ci, prob.pj
    n_cams, p = params.shape
    g = len(shared)
    sel = np.flatnonzero(shared_free)
    struct = _structure(n_cams, len(points), p, ci, pj, fixed)
    n_chunks = max(1, min(threads, len(points) // 256))
    free_rows = 1.0 - fixed.astype(np.float64)
    ev = prob.evaluate(params, points, shared)
    initial_cost = ev.cost
    history = [ev.cost]
    radius, nu = options.initial_radius, 2.0
    iterations = accepted = invalid = 0
    grad0 = None
    termination = "max_iterations"
    need_blocks = True
    dg = np.zeros(g)
    while iterations < options.max_iterations:
        if need_blocks:
            sw = np.sqrt(ev.w)
            r_w = ev.r * sw[:, None]
            Jc_w = ev.Jc * sw[:, None, None]
            Jp_w = ev.Jp * sw[:, None, None]
            U, V, W, gc, gp = _normal_blocks(Jc_w, Jp_w, r_w, ci, pj, n_cams, len(points))
            if ev.e_c is not None:  # the centre prior touches each camera alone
                U += np.einsum("nka,nkb->nab", ev.J_c, ev.J_c)
                gc += np.einsum("nka,nk->na", ev.J_c, ev.e_c)
            if g:
                Jg_w = ev.Jg * sw[:, None, None]
                H, G, Wg, gg = _shared_blocks(Jc_w, Jp_w, Jg_w, r_w, ci, pj, n_cams, len(points))
                if ev.e_g is not None:
                    G[np.diag_indices(g)] += ev.d_g**2
                    gg += ev.d_g * ev.e_g
            gmax = max(float(np.abs(gc * free_rows).max(initial=0.0)), float(np.abs(gp).max(initial=0.0)),
                       float(np.abs(gg[sel]).max(initial=0.0)) if g else 0.0)
            grad0 = gmax if grad0 is None else grad0
            if gmax <= options.gradient_tolerance * max(grad0, 1e-300):
                termination = "gradient_tolerance"
                break
            need_blocks = False
        iterations += 1
        mu = 1.0 / radius
        blocks, rhs, Vinv = _schur(U, V, W, gc, gp, ci, struct.order, struct.point_start, struct.pair_block,
                                   struct.pair_start, struct.blk_indptr, struct.blk_indices, mu, n_chunks)
        dc = dp = None
        if len(sel):
            Scg, Sgg, rg = _shared_schur(W, Vinv, Wg, gp, ci, struct.order, struct.point_start, n_cams)
            border = (H - Scg)[:, :, sel].reshape(n_cams * p, len(sel))
            corner = (G - Sgg)[np.ix_(sel, sel)]
            corner[np.diag_indices(len(sel))] += mu * np.clip(np.diag(G)[sel], _MIN_DIAG, _MAX_DIAG)
            sol = _solve_bordered(struct, blocks, rhs, border, corner, (rg - gg)[sel], options.dense_limit)
            if sol is not None:
                x, y = sol
                dg = np.zeros(g)
                dg[sel] = y
        else:
            x = _solve_reduced(struct, blocks, rhs, options.dense_limit)
        trial = None
        if x is not None:
            dc = np.zeros(n_cams * p)
            dc[struct.free_index >= 0] = x
            dc = dc.reshape(n_cams, p)
            gp_step = gp + Wg @ dg if len(sel) else gp
            dp = _back_substitute(dc, W, Vinv, gp_step, ci, struct.order, struct.point_start)
            if np.all(np.isfinite(dp)):
                new_params = prob.model.retract(params, dc)
                new_points = points + dp
                new_shared = shared + dg
                trial = prob.evaluate(new_params, new_points, new_shared)
        if trial is None or not np.isfinite(trial.cost):
            invalid += 1
            if invalid > options.max_invalid_steps:
                termination = "invalid_steps"
                break
            radius, nu = radius / nu, nu * 2.0
            if callback is not None:
                callback(iterations, ev.cost)
            continue
        invalid = 0
        step_norm = math.sqrt(float((dc * dc).sum() + (dp * dp).sum() + (dg * dg).sum()))
        x_norm = math.sqrt(float((params * params).sum() + (points * points).sum() + (shared * shared).sum()))
        if step_norm <= options.parameter_tolerance * (x_norm + options.parameter_tolerance):
            termination = "parameter_tolerance"
            break
        if g:
            predicted = _model_decrease_shared(Jc_w, Jp_w, Jg_w, r_w, dc, dp, dg, ci, pj)
        else:
            predicted = _model_decrease(Jc_w, Jp_w, r_w, dc, dp, ci, pj)
        predicted += _prior_decrease(ev, dc, dg)
        rho = (ev.cost - trial.cost) / predicted if predicted > 0 else -1.0
        if rho > 1e-3:
            change = ev.cost - trial.cost
            params, points, shared = new_params, new_points, new_shared
            ev = trial
            need_blocks = True
            accepted += 1
            history.append(ev.cost)
            # Ceres' rule (Nielsen) grows the radius by at most 3x and hardly at all for 0.5 < rho < 0.8,
            # where BAL problems sit for dozens of steps: the damping then, not the model, sets the pace
            # (BAL-49 needs 64 accepted steps to reach Ceres' 100-iteration cost; 4x growth: 28).
            growth = _RADIUS_GROWTH if rho > 0.5 else 1.0 / max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            radius = min(radius * growth, 1e16)
            nu = 2.0
        else:
            radius, nu = radius / nu, nu * 2.0
        if callback is not None:
            callback(iterations, ev.cost)
        if rho > 1e-3 and change <= options.function_tolerance * max(history[-2], 1e-300):
            termination = "function_tolerance"
            break
    return BAResult(params=params, points=points, initial_cost=initial_cost, final_cost=ev.cost,
                    iterations=iterations, accepted=accepted, termination=termination, seconds=0.0, history=history,
                    shared=shared.copy() if g else None)


def _prior_decrease(ev: _Evaluation, dc: np.ndarray, dg: np.ndarray) -> float:
    """Decrease of the priors' linearised cost for the step (dc, dg)."""
    total = 0.0
    if ev.e_g is not None:
        jd = ev.d_g * dg
        total += float(-(ev.e_g * jd).sum() - 0.5 * (jd * jd).sum())
    if ev.e_c is not None:
        jd = np.einsum("nka,na->nk", ev.J_c, dc)
        total += float(-(ev.e_c * jd).sum() - 0.5 * (jd * jd).sum())
    return total


def reprojection_errors(model: CameraModel, params: np.ndarray, points: np.ndarray,
                        cam_idx: np.ndarray, pt_idx: np.ndarray, obs: np.ndarray) -> np.ndarray:
    """Per-observation reprojection error (N,) in pixels."""
    r, _, _ = model.evaluate(np.ascontiguousarray(params, np.float64), np.ascontiguousarray(points, np.float64),
                             np.ascontiguousarray(cam_idx, np.int64), np.ascontiguousarray(pt_idx, np.int64),
                             np.ascontiguousarray(obs, np.float64), False)
    return np.sqrt(np.einsum("ij,ij->i", r, r))


def shared_information(model: CameraModel, params: np.ndarray, points: np.ndarray, shared: np.ndarray,
                       cam_idx: np.ndarray, pt_idx: np.ndarray, obs: np.ndarray, fixed: np.ndarray,
                       options: BAOptions = BAOptions()) -> np.ndarray:
    """What the observations alone say about the shared parameters: their Fisher information (g, g)
    at the given solution (no prior), with every point and free camera parameter estimated too (the
    Schur complement of the Gauss-Newton matrix onto the shared block; residuals in pixels, unit
    variance, the robust loss's weights). Its inverse's diagonal holds the variances the images
    alone would give; a direction they do not determine (a flat scene seen from above: focal length
    against altitude) has little information. The gauge directions left free (scale) get a
    negligible damping, 1e-9 of the diagonal."""
    g = int(model.n_shared)
    prob = _Problem(model, np.ascontiguousarray(cam_idx, np.int64), np.ascontiguousarray(pt_idx, np.int64),
                    np.ascontiguousarray(obs, np.float64), options)
    params = np.ascontiguousarray(params, np.float64)
    points = np.ascontiguousarray(points, np.float64)
    ev = prob.evaluate(params, points, np.ascontiguousarray(shared, np.float64))
    ci, pj = prob.ci, prob.pj
    n_cams, p = params.shape
    struct = _structure(n_cams, len(points), p, ci, pj, fixed)
    sw = np.sqrt(ev.w)
    r_w, Jc_w, Jp_w, Jg_w = ev.r * sw[:, None], ev.Jc * sw[:, None, None], ev.Jp * sw[:, None, None], \
        ev.Jg * sw[:, None, None]
    with threadpool_limits(1, user_api="blas"):
        U, V, W, gc, gp = _normal_blocks(Jc_w, Jp_w, r_w, ci, pj, n_cams, len(points))
        H, G, Wg, _ = _shared_blocks(Jc_w, Jp_w, Jg_w, r_w, ci, pj, n_cams, len(points))
        blocks, _, Vinv = _schur(U, V, W, gc, gp, ci, struct.order, struct.point_start, struct.pair_block,
                                 struct.pair_start, struct.blk_indptr, struct.blk_indices, 1e-9, 1)
        Scg, Sgg, _ = _shared_schur(W, Vinv, Wg, gp, ci, struct.order, struct.point_start, n_cams)
        keep = struct.free_index >= 0
        B = (H - Scg).reshape(n_cams * p, g)[keep]
        info = G - Sgg
        if struct.n_free:
            solve_s = _factorise(struct, blocks, options.dense_limit)
            if solve_s is None:
                return np.zeros((g, g))
            info = info - B.T @ solve_s(B)
    return 0.5 * (info + info.T)


def iteration_steps(model: CameraModel, params: np.ndarray, points: np.ndarray, cam_idx: np.ndarray,
                    pt_idx: np.ndarray, obs: np.ndarray, fixed: np.ndarray,
                    step: Callable[[str, Callable[[], object]], object], mu: float = 1e-4,
                    dense_limit: int = 2000) -> dict[str, int]:
    """One damped step of :func:`solve`'s Schur path (no robust loss, no shared intrinsics), each stage run as
    ``step(name, fn)``, which must return ``fn()`` (a benchmark times it): residuals_and_jacobians,
    normal_equation_blocks, schur_complement, reduced_system_cholesky, back_substitution, model_decrease.

    params (n_cams, p) and fixed (n_cams, p) bool per the model; points (n_pts, 3); cam_idx, pt_idx (M,) int64;
    obs (M, 2) pixels; mu: the damping. Returns the reduced system's size: ``reduced_unknowns``, ``point_pairs``."""
    n_cams, n_pts = len(params), len(points)
    st = _structure(n_cams, n_pts, model.n_params, cam_idx, pt_idx, fixed)
    r, Jc, Jp = step("residuals_and_jacobians", lambda: model.evaluate(params, points, cam_idx, pt_idx, obs, True))
    U, V, W, gc, gp = step("normal_equation_blocks",
                           lambda: _normal_blocks(Jc, Jp, r, cam_idx, pt_idx, n_cams, n_pts))
    blocks, rhs, Vinv = step("schur_complement", lambda: _schur(
        U, V, W, gc, gp, cam_idx, st.order, st.point_start, st.pair_block, st.pair_start, st.blk_indptr,
        st.blk_indices, mu, 1))
    x = step("reduced_system_cholesky", lambda: _solve_reduced(st, blocks, rhs, dense_limit))
    dc = np.zeros(n_cams * model.n_params)
    dc[st.free_index >= 0] = x
    dc = dc.reshape(n_cams, model.n_params)
    dp = step("back_substitution", lambda: _back_substitute(dc, W, Vinv, gp, cam_idx, st.order, st.point_start))
    step("model_decrease", lambda: _model_decrease(Jc, Jp, r, dc, dp, cam_idx, pt_idx))
    return {"reduced_unknowns": st.n_free, "point_pairs": int((st.pair_block >= 0).sum())}
