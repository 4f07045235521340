"""Bjøntegaard delta rate and PSNR through the maintained ``bjontegaard`` package (FAU-LMS).

Two interpolations of the rate-distortion curves: ``"cubic"`` (VCEG-M33, Bjøntegaard 2001: one
cubic through the points of log-rate against PSNR) and ``"pchip"`` (piecewise cubic Hermite, the
JCT-VC/JCT-3V common-test-conditions spreadsheet). Rates in any unit (bits), PSNR in dB.

BD-rate (%) is the average rate difference of the test against the anchor at equal quality over
the PSNR range both curves cover (negative: the test needs fewer bits); BD-PSNR (dB) the average
quality difference at equal rate. A post-filter does not change the bitstream, so its rate points
equal the anchor's and BD-PSNR always has the full overlap, while BD-rate needs the PSNR ranges to
overlap: :func:`bd_pair` returns the overlap too, and NaN where the curves do not overlap at all.
"""
from __future__ import annotations

import warnings
from typing import Sequence

import numpy as np

INTERPOLATIONS = ("pchip", "cubic")


def _curves(rate: Sequence[float], psnr: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    r, p = np.asarray(rate, np.float64), np.asarray(psnr, np.float64)
    if r.shape != p.shape or r.ndim != 1 or r.size < 4:
        raise ValueError(f"need at least 4 rate/PSNR points of equal count, got {r.shape} and {p.shape}")
    if not (np.isfinite(r).all() and np.isfinite(p).all() and (r > 0).all()):
        raise ValueError("rates must be positive and finite, PSNRs finite")
    order = np.argsort(r)
    return r[order], p[order]


def psnr_overlap(psnr_anchor: Sequence[float], psnr_test: Sequence[float]) -> float:
    """Share (0..1) of the union of the two PSNR ranges that both cover (the BD-rate integration interval)."""
    a, t = np.asarray(psnr_anchor, float), np.asarray(psnr_test, float)
    lo, hi = max(a.min(), t.min()), min(a.max(), t.max())
    span = max(a.max(), t.max()) - min(a.min(), t.min())
    return float(max(hi - lo, 0.0) / span) if span > 0 else 1.0


def bd_rate(rate_anchor: Sequence[float], psnr_anchor: Sequence[float], rate_test: Sequence[float],
            psnr_test: Sequence[float], method: str = "pchip") -> float:
    """BD-rate of the test against the anchor, percent (NaN when the PSNR ranges do not overlap)."""
    return _bjontegaard("bd_rate", rate_anchor, psnr_anchor, rate_test, psnr_test, method)


def bd_psnr(rate_anchor: Sequence[float], psnr_anchor: Sequence[float], rate_test: Sequence[float],
            psnr_test: Sequence[float], method: str = "pchip") -> float:
    """BD-PSNR of the test against the anchor, dB (positive: the test is better at equal rate)."""
    return _bjontegaard("bd_psnr", rate_anchor, psnr_anchor, rate_test, psnr_test, method)


def _bjontegaard(measure: str, rate_anchor: Sequence[float], psnr_anchor: Sequence[float],
                 rate_test: Sequence[float], psnr_test: Sequence[float], method: str) -> float:
    """``bjontegaard.<measure>`` on the two curves, with the interpolation ``method`` checked."""
    import bjontegaard

    if method not in INTERPOLATIONS:
        raise ValueError(f"unknown interpolation {method!r}; expected one of {', '.join(INTERPOLATIONS)}")
    ra, pa = _curves(rate_anchor, psnr_anchor)
    rt, pt = _curves(rate_test, psnr_test)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # low overlap is reported by bd_pair, not as a warning
        return float(getattr(bjontegaard, measure)(ra, pa, rt, pt, method=method, min_overlap=0))


def bd_pair(rate_anchor: Sequence[float], psnr_anchor: Sequence[float], rate_test: Sequence[float],
            psnr_test: Sequence[float]) -> dict[str, float]:
    """All figures of one comparison: ``rate_pchip``/``rate_cubic`` (%), ``psnr_pchip``/``psnr_cubic``
    (dB) and ``overlap`` (share of the PSNR ranges both curves cover)."""
    out = {f"rate_{m}": bd_rate(rate_anchor, psnr_anchor, rate_test, psnr_test, m) for m in INTERPOLATIONS}
    out.update({f"psnr_{m}": bd_psnr(rate_anchor, psnr_anchor, rate_test, psnr_test, m) for m in INTERPOLATIONS})
    out["overlap"] = psnr_overlap(psnr_anchor, psnr_test)
    return out
