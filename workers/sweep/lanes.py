"""The depth search (variance cost) over LANES adjacent virtual pixels at once, in LLVM vector code.

Same definition and the same result as a pixel-by-pixel search (positions rounded to 1/2**bits px,
the packed fixed-point bilinear samples of :func:`workers.sweep.kernels.pack_images`, a camera votes when
its four taps are in its image, the variance summed over B, G, R, ties to the nearer plane, exact pruning);
see :func:`workers.sweep.kernels.sweep_depth` for the contract.

How: the LANES pixels of a row segment test the same plane together. One call of :func:`_plane_sweep`
runs the camera loop for a plane with every per-lane quantity in a vector register: the projective
division, the rounding to fixed point (the 1.5 * 2**52 trick: exact round-half-even, no int64 conversion
needed), the tap addresses, the packed-lane bilinear blend (64-bit integer vectors), the sums and the
pruning bound. A lane is pruned on its own; the plane stops once every lane is pruned. The sampling does
not wait for the previous camera's pruning test (a pruned lane's samples are computed and ignored), so
consecutive cameras overlap in the pipeline. Only generic LLVM vector instructions are used: on x86-64
with AVX2 a 16-lane float64 operation is four 4-wide instructions; other targets split them their way.

Exact pruning: the planes chosen by the pixel left of the lanes and by those above them (within the
band) are tested first, and a lane abandons a plane once the cameras sampled so far prove that it cannot
beat the lane's best one: their squared deviations from their own mean bound n times the cost from below,
with n at most the voters so far plus the cameras left. The bound is widened by a few ulps (``_SAFE``) so
that rounding never cuts a plane whose rounded cost ties the best one: the result equals the full search
(argmin of the float64 costs, ties to the nearer plane) in any order the planes are tried.

Measured on the 2-core benchmark machine (10 cameras at 640x480, virtual view 640x480, 32 planes, the
sweep stage, medians of 7 interleaved runs): 341 ms pixel by pixel, 214 ms with 16 lanes, the same
choice at every pixel; 4, 8 and 32 lanes were slower than 16 (less independent work per instruction, or
more samples of lanes already pruned).
"""
from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.extending import intrinsic

from .layout import BIG as _BIG
from .layout import CAM_F, CAM_I, TILE_COLS
from .layout import FAST as _FAST
from .layout import SAFE as _SAFE
from .layout import Z_MIN as _Z_MIN

LANES = 16
_D = ir.VectorType(ir.DoubleType(), LANES)
_Q = ir.VectorType(ir.IntType(64), LANES)
_I32 = ir.IntType(32)
_I64 = ir.IntType(64)
_ROUND = 6755399441055744.0  # 1.5 * 2**52: x + _ROUND holds round-half-even(x) in its low bits, |x| < 2**51
_ROUND_BITS = int(np.float64(_ROUND).view(np.int64))
_CLAMP = 2.0**50  # positions beyond any image, small enough for _ROUND
_EXP52 = 0x4330000000000000  # bits of 2**52: an integer < 2**52 or-ed into them is 2**52 + that integer
# rows of a lane search's state array, LANES float64 each
ROW_BC_SAFE, ROW_BJ, ROW_N, ROW_NSSD = range(4)
STATE_ROWS = 4


def _splat(builder, x, vty):
    v = builder.insert_element(ir.Constant(vty, ir.Undefined), x, ir.Constant(_I32, 0))
    return builder.shuffle_vector(v, ir.Constant(vty, ir.Undefined), ir.Constant(ir.VectorType(_I32, LANES), [0] * LANES))


def _const(vty, value):
    return ir.Constant(vty, [value] * LANES)


def _row_ptr(builder, base, row):
    p = builder.gep(base, [ir.Constant(_I64, row * LANES)], inbounds=True)
    return builder.bitcast(p, _D.as_pointer())


# Every vector load and store says the alignment the array really has: a float64's 8 bytes. Without it LLVM
# assumes the vector type's own alignment (128 bytes for <16 x double>) and emits aligned moves; on AVX-512
# those are 64-byte `vmovaps zmm`, while numba and numpy allocate with 16- or 32-byte alignment, so the
# move faults whenever an array happens not to sit on a 64-byte boundary (a SIGSEGV one run in a few).
_ALIGN = 8


def _vload(builder, ptr):
    return builder.load(ptr, align=_ALIGN)


def _vstore(builder, value, ptr):
    builder.store(value, ptr, align=_ALIGN)


def _concat(builder, parts):
    """One vector of the given equal-width vectors, in order (a power-of-two count)."""
    while len(parts) > 1:
        w = parts[0].type.count
        mask = ir.Constant(ir.VectorType(_I32, 2 * w), list(range(2 * w)))
        parts = [builder.shuffle_vector(parts[k], parts[k + 1], mask) for k in range(0, len(parts), 2)]
    return parts[0]


def _rounded(builder, x):
    """round-half-even(x) as int64 lanes (x float64 lanes; NaN and |x| > 2**50 clamp to -+2**50)."""
    lo, hi = _const(_D, -_CLAMP), _const(_D, _CLAMP)
    x = builder.select(builder.fcmp_ordered(">", x, lo), x, lo)
    x = builder.select(builder.fcmp_ordered("<", x, hi), x, hi)
    t = builder.fadd(x, _const(_D, _ROUND))
    return builder.sub(builder.bitcast(t, _Q), _const(_Q, _ROUND_BITS))


def _taps(builder, pixp, o, row):
    """The four bilinear taps (p00, p01, p10, p11: int64 lanes) at element offsets o (int64 lanes) of the
    packed pixels; each row's two taps are one 16-byte load per lane."""
    pair = ir.VectorType(_I64, 2)
    first, second = ir.Constant(ir.VectorType(_I32, 2), [0, 2]), ir.Constant(ir.VectorType(_I32, 2), [1, 3])
    idx = [builder.extract_element(o, ir.Constant(_I32, k)) for k in range(LANES)]
    out = []
    for d in (ir.Constant(_I64, 0), row):
        pairs = [builder.load(builder.bitcast(builder.gep(pixp, [builder.add(i, d)], inbounds=True), pair.as_pointer()),
                              align=_ALIGN) for i in idx]
        out.append(_concat(builder, [builder.shuffle_vector(pairs[k], pairs[k + 1], first) for k in range(0, LANES, 2)]))
        out.append(_concat(builder, [builder.shuffle_vector(pairs[k], pairs[k + 1], second) for k in range(0, LANES, 2)]))
    return out


def _sil_lookup(builder, silp, base, stride, u, v, ok):
    """Silhouette byte (int64 lanes) at the pixel nearest to (u, v) px for lanes in ok, else at base."""
    nu = builder.select(ok, _rounded(builder, u), _const(_Q, 0))
    nv = builder.select(ok, _rounded(builder, v), _const(_Q, 0))
    low32 = _const(_Q, 0xFFFFFFFF)
    o = builder.add(builder.add(base, builder.mul(builder.and_(nv, low32), builder.and_(stride, low32))), nu)
    out = ir.Constant(_Q, ir.Undefined)
    for k in range(LANES):
        i = builder.extract_element(o, ir.Constant(_I32, k))
        byte = builder.load(builder.gep(silp, [i], inbounds=True))
        out = builder.insert_element(out, builder.zext(byte, _I64), ir.Constant(_I32, k))
    return out


def _plane_sweep_codegen(use_hull: bool):
    def codegen(context, builder, signature, args):
        pixv, silv, alv, cfv, civ, ncv, sv, scv, ubv, alivev, jfv, stv = args
        arr = lambda k, v: context.make_array(signature.args[k])(context, builder, v).data
        pixp, silp, alp, cfp, cip, stp = arr(0, pixv), arr(1, silv), arr(2, alv), arr(3, cfv), arr(4, civ), arr(11, stv)
        c = lambda v: ir.Constant(_I64, v)
        fl = ("contract",)
        zero_d, zero_q = _const(_D, 0.0), _const(_Q, 0)
        lanes = ir.Constant(_Q, [1 << k for k in range(LANES)])
        s = _splat(builder, sv, _D)
        scale = _splat(builder, scv, _D)
        unscale = builder.fdiv(_const(_D, 1.0), scale)  # a power of two: exact
        ub = _splat(builder, ubv, _Q)
        fmask = builder.and_(builder.sub(builder.shl(_const(_Q, 1), ub), _const(_Q, 1)), _const(_Q, 63))
        low32 = _const(_Q, 0xFFFFFFFF)  # tells LLVM the row product fits one 32x32->64 multiply
        bc_safe = _vload(builder, _row_ptr(builder, stp, ROW_BC_SAFE))
        farther = builder.fcmp_ordered(">", _splat(builder, jfv, _D), _vload(builder, _row_ptr(builder, stp, ROW_BJ)))
        n_cam = builder.sitofp(ncv, ir.DoubleType())

        entry = builder.block
        loop = builder.append_basic_block("camera")
        done = builder.append_basic_block("plane_done")
        builder.branch(loop)
        builder.position_at_end(loop)
        m = builder.phi(_I64)
        alive = builder.phi(_I64)
        acc = [builder.phi(_D) for _ in range(5)]  # per lane: sums of B, G, R, sum of squares, votes
        m.add_incoming(c(0), entry)
        alive.add_incoming(alivev, entry)
        for p in acc:
            p.add_incoming(zero_d, entry)
        s0, s1, s2, sq, n = acc

        fb, ib, ab = builder.mul(m, c(CAM_F)), builder.mul(m, c(CAM_I)), builder.mul(m, c(3 * LANES))
        camf = lambda k: builder.load(builder.gep(cfp, [builder.add(fb, c(k))], inbounds=True))
        cami = lambda k: builder.load(builder.gep(cip, [builder.add(ib, c(k))], inbounds=True))
        a = [_vload(builder, builder.bitcast(builder.gep(alp, [builder.add(ab, c(r * LANES))], inbounds=True),
                                             _D.as_pointer())) for r in range(3)]
        b = [_splat(builder, camf(9 + r), _D) for r in range(3)]
        hz = builder.fadd(a[2], builder.fmul(s, b[2], flags=fl), flags=fl)
        per = builder.fmul(builder.fdiv(_const(_D, 1.0), hz), scale)
        u = builder.fmul(builder.fadd(a[0], builder.fmul(s, b[0], flags=fl), flags=fl), per)  # in 1/scale px
        v = builder.fmul(builder.fadd(a[1], builder.fmul(s, b[1], flags=fl), flags=fl), per)
        X, Y = _rounded(builder, u), _rounded(builder, v)
        valid = builder.and_(builder.fcmp_ordered(">", hz, _const(_D, _Z_MIN)),
                             builder.and_(builder.icmp_unsigned("<=", X, _splat(builder, cami(0), _Q)),
                                          builder.icmp_unsigned("<=", Y, _splat(builder, cami(1), _Q))))
        X, Y = builder.select(valid, X, zero_q), builder.select(valid, Y, zero_q)
        row = cami(3)
        o = builder.add(builder.add(_splat(builder, cami(2), _Q),
                                    builder.mul(builder.and_(builder.lshr(Y, ub), low32),
                                                builder.and_(_splat(builder, row, _Q), low32))),
                        builder.lshr(X, ub))
        fx, fy = builder.and_(X, fmask), builder.and_(Y, fmask)
        p00, p01, p10, p11 = _taps(builder, pixp, o, row)
        top = builder.add(builder.shl(p00, ub), builder.mul(builder.sub(p01, p00), fx))
        bot = builder.add(builder.shl(p10, ub), builder.mul(builder.sub(p11, p10), fx))
        val = builder.add(builder.shl(top, ub), builder.mul(builder.sub(bot, top), fy))
        lane = _const(_Q, (1 << 21) - 1)

        def as_double(iv):  # an integer below 2**52, exactly; 0 for lanes without a vote
            d = builder.fsub(builder.bitcast(builder.or_(iv, _const(_Q, _EXP52)), _D), _const(_D, 2.0**52))
            return builder.select(valid, d, zero_d)

        ch = [as_double(builder.and_(val, lane)), as_double(builder.and_(builder.lshr(val, _const(_Q, 21)), lane)),
              as_double(builder.lshr(val, _const(_Q, 42)))]
        s0n, s1n, s2n = builder.fadd(s0, ch[0]), builder.fadd(s1, ch[1]), builder.fadd(s2, ch[2])
        sqn = sq
        for x in ch:
            sqn = builder.fadd(sqn, builder.fmul(x, x, flags=fl), flags=fl)
        nn = builder.fadd(n, builder.select(valid, _const(_D, 1.0), zero_d))
        # n SSD (exact) against bc_safe n n_all, n_all <= n + cameras after this one; >= for a farther plane
        nssd = builder.fsub(builder.fmul(nn, sqn),
                            builder.fadd(builder.fadd(builder.fmul(s0n, s0n), builder.fmul(s1n, s1n)),
                                         builder.fmul(s2n, s2n)))
        m1 = builder.add(m, c(1))
        after = _splat(builder, builder.fsub(n_cam, builder.sitofp(m1, ir.DoubleType())), _D)
        rhs = builder.fmul(bc_safe, builder.fmul(nn, builder.fadd(nn, after)))
        cut = builder.or_(builder.fcmp_ordered(">", nssd, rhs),
                          builder.and_(builder.fcmp_ordered("==", nssd, rhs), farther))
        cut = builder.and_(cut, builder.fcmp_ordered(">=", nn, _const(_D, 2.0)))
        if use_hull:  # a vote outside the camera's silhouette: the point is outside the hull
            sil = _sil_lookup(builder, silp, _splat(builder, cami(4), _Q), _splat(builder, cami(5), _Q),
                              builder.fmul(u, unscale), builder.fmul(v, unscale), valid)
            cut = builder.or_(cut, builder.and_(valid, builder.icmp_unsigned("==", sil, zero_q)))
        was = builder.icmp_unsigned("!=", builder.and_(_splat(builder, alive, _Q), lanes), zero_q)
        keep = builder.and_(was, builder.not_(cut))
        alive_n = builder.zext(builder.bitcast(keep, ir.IntType(LANES)), _I64)
        more = builder.and_(builder.icmp_unsigned("!=", alive_n, c(0)), builder.icmp_signed("<", m1, ncv))
        end = builder.block
        m.add_incoming(m1, end)
        alive.add_incoming(alive_n, end)
        for p, new in zip(acc, (s0n, s1n, s2n, sqn, nn)):
            p.add_incoming(new, end)
        builder.cbranch(more, loop, done)
        builder.position_at_end(done)
        _vstore(builder, nn, _row_ptr(builder, stp, ROW_N))
        _vstore(builder, nssd, _row_ptr(builder, stp, ROW_NSSD))
        return alive_n

    return codegen


def _plane_sweep_intrinsic(use_hull: bool):
    @intrinsic
    def plane_sweep(typingctx, pix, sil, A, camf, cami, n_cam, s, scale, bits, alive, jf, state):
        """Samples camera after camera at inverse depth s for the lanes in the bit mask ``alive`` and
        returns the mask of lanes never pruned (those that voted with every camera they see). pix: packed
        pixels (uint64, flattened); sil: silhouettes (uint8, flattened; read with the hull only); A: (N, 3,
        LANES) float64 a_i(x, y) of the lanes; camf, cami: the kernels' camera tables; scale = 2**bits;
        jf: the plane's index; state (STATE_ROWS, LANES) float64: bc * _SAFE and the best plane per lane
        in, votes and n SSD of the plane out."""
        sig = types.int64(pix, sil, A, camf, cami, n_cam, s, scale, bits, alive, jf, state)
        return sig, _plane_sweep_codegen(use_hull)

    return plane_sweep


_plane_sweep = _plane_sweep_intrinsic(False)
_plane_sweep_hull = _plane_sweep_intrinsic(True)


def _lane_search(use_hull: bool):
    """:func:`lane_depth_search` compiled for one visual-hull setting (a constant of the compiled code)."""

    @njit(cache=True, parallel=True, fastmath=_FAST, error_model="numpy")
    def search(camf, cami, pix, silflat, min_views, bits, s_planes, lo, hi, bands, band_h, best,
               best_cost):  # pragma: no cover - compiled
        n_cam = cami.shape[0] // CAM_I
        h, w = best.shape
        scale = float(1 << bits)
        inv_s4 = 1.0 / scale**4  # samples are in units of 2**-2bits, squares in 2**-4bits
        for k in prange(bands.shape[0]):
            A = np.empty(n_cam * 3 * LANES)
            state = np.zeros(STATE_ROWS * LANES)
            order = np.empty(s_planes.shape[0], np.int64)  # distinct planes of the lanes' windows
            bc = np.empty(LANES)  # best cost per lane (the state holds it widened, and the best plane)
            y_a = bands[k] * band_h
            rows = min(band_h, h - y_a)
            for tr in range(rows * (-(-w // TILE_COLS))):  # the band tile by tile, so cameras' data stays in cache
                x_a = (tr // rows) * TILE_COLS
                y = y_a + tr % rows
                yf = float(y)
                for x0 in range(x_a, min(x_a + TILE_COLS, w), LANES):
                    nl = min(LANES, w - x0)
                    j_lo = s_planes.shape[0]
                    j_hi = -1
                    for t in range(LANES):
                        bc[t] = _BIG
                        state[ROW_BC_SAFE * LANES + t] = _BIG * _SAFE
                        state[ROW_BJ * LANES + t] = -1.0
                    for t in range(nl):
                        j_lo = min(j_lo, np.int64(lo[y, x0 + t]))
                        j_hi = max(j_hi, np.int64(hi[y, x0 + t]))
                    if j_lo <= j_hi:
                        for m in range(n_cam):
                            f = m * CAM_F
                            for t in range(LANES):
                                xf = float(x0 + t)
                                A[(3 * m) * LANES + t] = camf[f] * xf + camf[f + 1] * yf + camf[f + 2]
                                A[(3 * m + 1) * LANES + t] = camf[f + 3] * xf + camf[f + 4] * yf + camf[f + 5]
                                A[(3 * m + 2) * LANES + t] = camf[f + 6] * xf + camf[f + 7] * yf + camf[f + 8]
                    # planes to test: the choices of the pixel left of the lanes and of those above them
                    # (within the band) first, as they usually win and then prune the others early
                    n_seed = 0
                    left = np.int64(best[y, x0 - 1]) if x0 > 0 else -1
                    if j_lo <= left <= j_hi:
                        order[n_seed] = left
                        n_seed += 1
                    for t in range(nl if y > y_a else 0):
                        up = np.int64(best[y - 1, x0 + t])
                        new = j_lo <= up <= j_hi
                        for r in range(n_seed):
                            new = new and order[r] != up
                        if new:
                            order[n_seed] = up
                            n_seed += 1
                    n_order = n_seed
                    for j in range(j_lo, j_hi + 1):
                        new = True
                        for r in range(n_seed):
                            new = new and order[r] != j
                        if new:
                            order[n_order] = j
                            n_order += 1
                    for r in range(n_order):
                        j = order[r]
                        alive = 0
                        for t in range(nl):
                            if lo[y, x0 + t] <= j <= hi[y, x0 + t]:
                                alive |= 1 << t
                        if alive == 0:
                            continue
                        s = s_planes[j]
                        if use_hull:
                            alive = _plane_sweep_hull(pix, silflat, A, camf, cami, n_cam, s, scale, bits, alive,
                                                      float(j), state)
                        else:
                            alive = _plane_sweep(pix, silflat, A, camf, cami, n_cam, s, scale, bits, alive, float(j),
                                                 state)
                        for t in range(nl):
                            if (alive >> t) & 1:
                                n = state[ROW_N * LANES + t]
                                if n >= min_views:
                                    cost = state[ROW_NSSD * LANES + t] / (n * n)
                                    if cost < bc[t] or (cost == bc[t] and j < state[ROW_BJ * LANES + t]):
                                        bc[t] = cost
                                        state[ROW_BC_SAFE * LANES + t] = cost * _SAFE
                                        state[ROW_BJ * LANES + t] = float(j)
                    for t in range(nl):
                        bj = np.int64(state[ROW_BJ * LANES + t])
                        best[y, x0 + t] = bj
                        best_cost[y, x0 + t] = bc[t] * inv_s4 if bj >= 0 else np.inf

    return search


_LANE_SEARCHES = {hull: _lane_search(hull) for hull in (False, True)}


def lane_depth_search(camf, cami, pix, silflat, use_hull, min_views, bits, s_planes, lo, hi, bands, band_h, best,
                      best_cost) -> None:
    """:func:`workers.sweep.kernels.sweep_depth` for the variance cost (same arguments but trunc2)."""
    _LANE_SEARCHES[bool(use_hull)](camf, cami, pix, silflat, np.int64(min_views), np.int64(bits), s_planes, lo, hi,
                                   bands, band_h, best, best_cost)


def _lane_volume(use_hull: bool):
    """:func:`lane_cost_volume` compiled for one visual-hull setting (a constant of the compiled code)."""

    @njit(cache=True, parallel=True, fastmath=_FAST, error_model="numpy")
    def volume(camf, cami, pix, silflat, min_views, bits, s_planes, lo, hi, bands, band_h, ssd,
               votes):  # pragma: no cover - compiled
        n_cam = cami.shape[0] // CAM_I
        h, w, n_planes = ssd.shape
        inv_s4 = 1.0 / float(1 << bits) ** 4  # squares are in units of 2**-4bits
        scale = float(1 << bits)
        for k in prange(bands.shape[0]):
            A = np.empty(n_cam * 3 * LANES)
            state = np.zeros(STATE_ROWS * LANES)
            for t in range(LANES):  # never pruned: every plane's sums come back
                state[ROW_BC_SAFE * LANES + t] = _BIG * _SAFE
                state[ROW_BJ * LANES + t] = -1.0
            y_a = bands[k] * band_h
            rows = min(band_h, h - y_a)
            for tr in range(rows * (-(-w // TILE_COLS))):
                x_a = (tr // rows) * TILE_COLS
                y = y_a + tr % rows
                yf = float(y)
                for x0 in range(x_a, min(x_a + TILE_COLS, w), LANES):
                    nl = min(LANES, w - x0)
                    j_lo = n_planes
                    j_hi = -1
                    for t in range(nl):
                        j_lo = min(j_lo, np.int64(lo[y, x0 + t]))
                        j_hi = max(j_hi, np.int64(hi[y, x0 + t]))
                        for j in range(n_planes):
                            ssd[y, x0 + t, j] = 0.0
                            votes[y, x0 + t, j] = 0.0
                    if j_lo > j_hi:
                        continue
                    for m in range(n_cam):
                        f = m * CAM_F
                        for t in range(LANES):
                            xf = float(x0 + t)
                            A[(3 * m) * LANES + t] = camf[f] * xf + camf[f + 1] * yf + camf[f + 2]
                            A[(3 * m + 1) * LANES + t] = camf[f + 3] * xf + camf[f + 4] * yf + camf[f + 5]
                            A[(3 * m + 2) * LANES + t] = camf[f + 6] * xf + camf[f + 7] * yf + camf[f + 8]
                    for j in range(j_lo, j_hi + 1):
                        alive = 0
                        for t in range(nl):
                            if lo[y, x0 + t] <= j <= hi[y, x0 + t]:
                                alive |= 1 << t
                        if alive == 0:
                            continue
                        if use_hull:
                            alive = _plane_sweep_hull(pix, silflat, A, camf, cami, n_cam, s_planes[j], scale, bits,
                                                      alive, float(j), state)
                        else:
                            alive = _plane_sweep(pix, silflat, A, camf, cami, n_cam, s_planes[j], scale, bits, alive,
                                                 float(j), state)
                        for t in range(nl):
                            n = state[ROW_N * LANES + t]
                            if (alive >> t) & 1 and n >= min_views:
                                ssd[y, x0 + t, j] = state[ROW_NSSD * LANES + t] / n * inv_s4
                                votes[y, x0 + t, j] = n

    return volume


_LANE_VOLUMES = {hull: _lane_volume(hull) for hull in (False, True)}


def lane_cost_volume(camf, cami, pix, silflat, use_hull, min_views, bits, s_planes, lo, hi, bands, band_h, ssd,
                     votes) -> None:
    """Every plane's photo-consistency sums, unpruned, on the sampling of :func:`lane_depth_search`.

    Arguments as :func:`workers.sweep.kernels.sweep_depth` (lo, hi (h, w) int32 windows; the variance cost).
    Writes ssd (h, w, P) float32: the sum over the voting cameras of the squared deviation of their
    sample from the samples' mean, summed over B, G, R (colour levels squared; the variance times the
    votes), and votes (h, w, P) float32: the cameras that voted. Both are 0 where a plane is outside the
    pixel's window, has fewer than ``min_views`` votes, or (hull) a vote falls outside a silhouette.
    """
    _LANE_VOLUMES[bool(use_hull)](camf, cami, pix, silflat, np.int64(min_views), np.int64(bits), s_planes, lo, hi,
                                  bands, band_h, ssd, votes)
