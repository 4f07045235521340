"""The sweep's depth search on an NVIDIA GPU (numba's CUDA target).

The same choice as the CPU search, computed in the other order: instead of pruning planes pixel by
pixel, every (pixel, plane) pair of the search windows is one GPU thread, which samples the cameras and
writes the photo-consistency sums of :mod:`workers.sweep.costs` (``ssd``: the voting cameras' squared
deviation from their mean, summed over B, G, R; ``votes``). Window aggregation is a separable box sum
of both, and the winner per pixel (ties to the nearer plane) gets the same parabola sub-plane offset as
:func:`workers.sweep.costs.winner`. Semi-global aggregation runs on the CPU
(:func:`workers.sweep.costs.semi_global`) over the windowed cost the GPU computed.

The samples are the CPU search's: positions rounded to 1/2**bits px, bilinear weights in those steps
(in floating point where the CPU blends packed integers, which gives the same values up to rounding), so
the sums agree to rounding; a pixel whose two best planes are nearly tied may choose the other one, and a
position within rounding of a half step may round the other way.

Volumes live on the GPU plane-major, (P, h, w), so that neighbouring threads read neighbouring pixels.
The frames (images and silhouettes) are uploaded once per frame set (:meth:`GpuSweep.set_frames`).
The kernels compile on first use in each process (the renderer's first GPU view pays for it).

Tests run these kernels on the CPU through numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``).
"""
from __future__ import annotations

import math

import numpy as np
from numba import cuda

from .costs import robust_cost, semi_global
from .costs import winner as cpu_winner
from .layout import Z_MIN

BLOCK = (32, 8, 1)  # threads per block: a warp along x, 8 rows


def available() -> bool:
    """Whether a real CUDA GPU can run the kernels (never the simulator: it is for tests only)."""
    try:
        from numba import config
        return bool(cuda.is_available()) and not config.ENABLE_CUDASIM
    except Exception:  # noqa: BLE001 - a broken driver means no GPU, not a failure of the renderer
        return False


@cuda.jit(device=True, inline=True)
def _lerp2(a, b, c, d, fx, fy):  # pragma: no cover - compiled
    top = a + fx * (b - a)
    bot = c + fx * (d - c)
    return top + fy * (bot - top)


@cuda.jit
def _volume_kernel(Q, B, imgs, sizes, sils, use_hull, min_views, scale, s_planes, lo, hi, ssd, votes):  # pragma: no cover
    """One thread per (x, y, plane): ssd, votes (P, h, w) float32 (0 outside the window lo..hi, below
    min_views votes, or outside the hull). Q (N, 3, 3), B (N, 3) float64 (see workers.sweep.kernels);
    imgs (N, Hm, Wm, 3) uint8; sizes (N, 2) int64 (W, H); sils (N, Hm, Wm) uint8; scale: 2**bits, the
    sampling grid's steps per pixel; s_planes (P,)."""
    x, y, j = cuda.grid(3)
    P, h, w = ssd.shape
    if x >= w or y >= h or j >= P:
        return
    ssd[j, y, x] = 0.0
    votes[j, y, x] = 0.0
    if j < lo[y, x] or j > hi[y, x]:
        return
    s = s_planes[j]
    xf = float(x)
    yf = float(y)
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    q = 0.0
    n = 0
    for i in range(Q.shape[0]):
        hz = Q[i, 2, 0] * xf + Q[i, 2, 1] * yf + Q[i, 2, 2] + s * B[i, 2]
        if hz <= Z_MIN:
            continue
        inv = 1.0 / hz
        u = (Q[i, 0, 0] * xf + Q[i, 0, 1] * yf + Q[i, 0, 2] + s * B[i, 0]) * inv
        v = (Q[i, 1, 0] * xf + Q[i, 1, 1] * yf + Q[i, 1, 2] + s * B[i, 1]) * inv
        wmax = sizes[i, 0] - 1
        hmax = sizes[i, 1] - 1
        # the CPU search's sampling grid: positions rounded to 1/scale px, inside when the rounded one is
        X = math.floor(u * scale + 0.5)
        Y = math.floor(v * scale + 0.5)
        if not (X >= 0.0 and X <= wmax * scale and Y >= 0.0 and Y <= hmax * scale):
            continue
        if use_hull and sils[i, int(v + 0.5), int(u + 0.5)] == 0:
            return  # outside the hull: the plane is no candidate here
        x0 = int(X / scale)
        y0 = int(Y / scale)
        fx = (X - x0 * scale) / scale
        fy = (Y - y0 * scale) / scale
        x1 = x0 + 1 if x0 < wmax else x0
        y1 = y0 + 1 if y0 < hmax else y0
        c0 = _lerp2(float(imgs[i, y0, x0, 0]), float(imgs[i, y0, x1, 0]), float(imgs[i, y1, x0, 0]),
                    float(imgs[i, y1, x1, 0]), fx, fy)
        c1 = _lerp2(float(imgs[i, y0, x0, 1]), float(imgs[i, y0, x1, 1]), float(imgs[i, y1, x0, 1]),
                    float(imgs[i, y1, x1, 1]), fx, fy)
        c2 = _lerp2(float(imgs[i, y0, x0, 2]), float(imgs[i, y0, x1, 2]), float(imgs[i, y1, x0, 2]),
                    float(imgs[i, y1, x1, 2]), fx, fy)
        s0 += c0
        s1 += c1
        s2 += c2
        q += c0 * c0 + c1 * c1 + c2 * c2
        n += 1
    if n == 0 or n < min_views:
        return
    ssd[j, y, x] = max(q - (s0 * s0 + s1 * s1 + s2 * s2) / n, 0.0)
    votes[j, y, x] = n


@cuda.jit
def _row_sums(ssd, votes, radius, out_ssd, out_votes):  # pragma: no cover - compiled
    """Sums over x - radius .. x + radius (pixels beyond the border count 0), per plane: (P, h, w)."""
    x, y, j = cuda.grid(3)
    P, h, w = ssd.shape
    if x >= w or y >= h or j >= P:
        return
    a = 0.0
    b = 0.0
    for xx in range(max(x - radius, 0), min(x + radius + 1, w)):
        a += ssd[j, y, xx]
        b += votes[j, y, xx]
    out_ssd[j, y, x] = a
    out_votes[j, y, x] = b


@cuda.jit
def _windowed_variance(row_ssd, row_votes, own_votes, radius, out):  # pragma: no cover - compiled
    """The column sums of the row sums: the windowed variance (P, h, w) float32 (inf where the pixel
    itself did not vote for the plane), as :func:`workers.sweep.costs.windowed_variance`."""
    x, y, j = cuda.grid(3)
    P, h, w = out.shape
    if x >= w or y >= h or j >= P:
        return
    if own_votes[j, y, x] <= 0:
        out[j, y, x] = math.inf
        return
    a = 0.0
    b = 0.0
    for yy in range(max(y - radius, 0), min(y + radius + 1, h)):
        a += row_ssd[j, yy, x]
        b += row_votes[j, yy, x]
    out[j, y, x] = a / b


@cuda.jit
def _winner_kernel(cost, subplane, best, value, offset):  # pragma: no cover - compiled
    """Lowest cost per pixel (ties to the nearer plane; -1 where all are inf) and the parabola vertex
    offset through its neighbour planes, as :func:`workers.sweep.costs.winner`; cost (P, h, w)."""
    x, y = cuda.grid(2)
    P, h, w = cost.shape
    if x >= w or y >= h:
        return
    bj = -1
    bc = math.inf
    for j in range(P):
        c = cost[j, y, x]
        if c < bc:
            bc = c
            bj = j
    best[y, x] = bj
    value[y, x] = bc
    d = 0.0
    if subplane and 0 < bj < P - 1:
        c0 = cost[bj - 1, y, x]
        c2 = cost[bj + 1, y, x]
        den = c0 - 2.0 * bc + c2
        if den > 0.0 and den < math.inf:
            d = min(0.5, max(-0.5, 0.5 * (c0 - c2) / den))
    offset[y, x] = d


def _grid3(h: int, w: int, p: int) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
    return (-(-w // BLOCK[0]), -(-h // BLOCK[1]), p), BLOCK


class GpuSweep:
    """One renderer's frames on the GPU and its depth choice there.

    imgs (N, Hm, Wm, 3) uint8 BGR, sils (N, Hm, Wm) uint8 and sizes (N, 2) int64 (W, H): the renderer's
    padded frame arrays (:class:`workers.sweep.renderer.SweepRenderer`)."""

    def __init__(self, imgs: np.ndarray, sils: np.ndarray, sizes: np.ndarray) -> None:
        self._imgs = cuda.to_device(np.ascontiguousarray(imgs))
        self._sils = cuda.to_device(np.ascontiguousarray(sils))
        self._sizes = cuda.to_device(np.ascontiguousarray(sizes, np.int64))
        self._volumes: dict[tuple[int, int, int], tuple] = {}

    def set_frames(self, imgs: np.ndarray, sils: np.ndarray) -> None:
        """Upload a new frame set (same shapes as the constructor's)."""
        self._imgs.copy_to_device(np.ascontiguousarray(imgs))
        self._sils.copy_to_device(np.ascontiguousarray(sils))

    def cost_sums(self, Q: np.ndarray, B: np.ndarray, s_planes: np.ndarray, use_hull: bool, min_views: int,
                  bits: int, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """ssd, votes (h, w, P) float32 on the host, as :func:`workers.sweep.lanes.lane_cost_volume`
        defines them (Q (N, 3, 3), B (N, 3) float64; s_planes (P,) 1/m; bits: sampling positions in
        1/2**bits px; lo, hi (h, w) int32 windows)."""
        ssd, votes, _, _, _ = self._sums(Q, B, s_planes, use_hull, min_views, bits, lo, hi)
        return (np.ascontiguousarray(ssd.copy_to_host().transpose(1, 2, 0)),
                np.ascontiguousarray(votes.copy_to_host().transpose(1, 2, 0)))

    def choose(self, Q: np.ndarray, B: np.ndarray, s_planes: np.ndarray, use_hull: bool, min_views: int,
               bits: int, lo: np.ndarray, hi: np.ndarray, aggregation: str, window: int, subplane: bool,
               cost_cap: float = 40.0, sgm_p1: float = 2.0, sgm_p2: float = 32.0, sgm_directions: int = 8,
               want_volume: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """Best plane (h, w) int32 (-1 none), its cost (h, w) float32, the sub-plane offset (h, w) float32
        (planes) and the cost volume it was chosen on, as :meth:`workers.sweep.renderer.SweepRenderer._choose`
        defines them for ``aggregation`` "none" (the per-pixel variance, no offset, no volume), "window" (the
        windowed variance over (2 window + 1)^2 px) or "sgm" (then semi-global aggregation on the CPU). The
        volume (h, w, P) float32 comes back to the host only when ``want_volume`` (the occlusion fill reads
        it) or when SGM made it there; else None."""
        ssd, votes, tmp_s, tmp_v, var = self._sums(Q, B, s_planes, use_hull, min_views, bits, lo, hi)
        P, h, w = var.shape
        grid, block = _grid3(h, w, P)
        radius = 0 if aggregation == "none" else int(window)
        _row_sums[grid, block](ssd, votes, radius, tmp_s, tmp_v)
        _windowed_variance[grid, block](tmp_s, tmp_v, votes, radius, var)
        if aggregation == "sgm":
            host = np.ascontiguousarray(var.copy_to_host().transpose(1, 2, 0))
            volume = semi_global(robust_cost(host, cost_cap), sgm_p1, sgm_p2, sgm_directions)
            best, value, offset = cpu_winner(volume)
            if not subplane:
                offset[:] = 0.0
            return best, value, offset, volume
        best = cuda.device_array((h, w), np.int32)
        value = cuda.device_array((h, w), np.float32)
        offset = cuda.device_array((h, w), np.float32)
        grid2 = (-(-w // BLOCK[0]), -(-h // BLOCK[1]))
        _winner_kernel[grid2, BLOCK[:2]](var, subplane and aggregation != "none", best, value, offset)
        volume = None
        if want_volume and aggregation != "none":
            volume = np.ascontiguousarray(var.copy_to_host().transpose(1, 2, 0))
        return best.copy_to_host(), value.copy_to_host(), offset.copy_to_host(), volume

    def _sums(self, Q, B, s_planes, use_hull, min_views, bits, lo, hi):
        h, w = lo.shape
        P = len(s_planes)
        key = (P, h, w)
        if key not in self._volumes:
            # a few shapes are in use at once (coarse-to-fine: two levels): allocating on the GPU per view
            # costs more than the search, so each shape's buffers are kept, the oldest dropped after four
            if len(self._volumes) >= 4:
                self._volumes.pop(next(iter(self._volumes)))
            self._volumes[key] = tuple(cuda.device_array(key, np.float32) for _ in range(5))
        ssd, votes, tmp_s, tmp_v, var = self._volumes[key]
        grid, block = _grid3(h, w, P)
        _volume_kernel[grid, block](
            cuda.to_device(np.ascontiguousarray(Q, np.float64)), cuda.to_device(np.ascontiguousarray(B, np.float64)),
            self._imgs, self._sizes, self._sils, bool(use_hull), int(min_views), float(1 << bits),
            cuda.to_device(np.ascontiguousarray(s_planes, np.float64)),
            cuda.to_device(np.ascontiguousarray(lo, np.int32)), cuda.to_device(np.ascontiguousarray(hi, np.int32)),
            ssd, votes)
        return ssd, votes, tmp_s, tmp_v, var
