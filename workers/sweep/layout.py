"""Constants shared by the compiled depth searches (:mod:`workers.sweep.kernels`, pixel by pixel, and
:mod:`workers.sweep.lanes`, 16 pixels at a time): the layout of the per-camera tables, the tiling, the
fast-math flags and the pruning bound's widening. Both kernels import them from here, so neither
imports the other's internals."""
from __future__ import annotations

# per-camera rows of the sweep's tables, in sampling order
CAM_F = 16  # float64: Q row-major (9), B (3), unused (4)
CAM_I = 8  # int64: (W-1) << bits, (H-1) << bits, image offset, image row stride, silhouette offset,
#            silhouette row stride, unused (2)
TILE_COLS = 32  # columns per tile of the sweep: a tile's cameras' data stays in cache across its rows
MAX_BITS = 6  # finest sampling step of the depth search: 1/64 px (lanes: 255 * 4**6 < 2**21)

Z_MIN = 1e-9  # a point this close to a camera's centre plane, or behind it, gets no vote from it
# fast-math without the no-NaN/no-inf assumptions (the kernels compare against infinities) and without
# approximate reciprocals (x / n must stay exact so that equal samples give exactly zero variance)
FAST = {"nsz", "contract", "afn", "reassoc"}

BIG = 1e300  # "no plane yet": finite, so that bc * n stays a valid bound
# the pruning bound is a rounded product: widened by a few ulps it never cuts a plane whose rounded cost ties or
# beats the best one, so the choice is the full search's whatever the order the planes are tried in
SAFE = 1.0 + 2.0**-50
