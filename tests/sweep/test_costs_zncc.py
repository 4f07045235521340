"""The exposure-proof costs of workers.sweep.costs (ZNCC over a window, best-k of the views) against plain
numpy definitions and known answers."""
import numpy as np
import pytest

from workers.sweep import costs


def _zncc_direct(ref, warped, r, min_std):
    """Plain python: 1 - ZNCC over the (2r+1)^2 window cut at the border, per pixel and plane."""
    h, w, P = warped.shape
    out = np.empty((h, w, P))
    for y in range(h):
        for x in range(w):
            ys, xs = slice(max(0, y - r), y + r + 1), slice(max(0, x - r), x + r + 1)
            a = ref[ys, xs].astype(np.float64).ravel()
            for j in range(P):
                b = warped[ys, xs, j].astype(np.float64).ravel()
                if a.std() < min_std:
                    out[y, x, j] = np.inf
                elif b.std() < min_std:
                    out[y, x, j] = 1.0
                else:
                    out[y, x, j] = 1.0 - np.mean((a - a.mean()) * (b - b.mean())) / (a.std() * b.std())
    return out


def test_window_count():
    n = costs.window_count(4, 5, 1)
    assert n[0, 0] == 4 and n[0, 2] == 6 and n[1, 1] == 9 and n.dtype == np.float32


@pytest.mark.parametrize("r", [0, 1, 2])
def test_zncc_cost_is_one_minus_the_window_correlation(r):
    rng = np.random.default_rng(2)
    ref = rng.uniform(0, 255, (7, 9)).astype(np.float32)
    warped = rng.uniform(0, 255, (7, 9, 4)).astype(np.float32)
    ref[0:3, 0:3] = 100.0  # a flat patch: no cost where the whole window is flat
    warped[..., 1] = 0.5 * ref + 20  # a perfect match up to gain and offset
    got = costs.zncc_cost(ref, warped, r, min_std=0.5)
    want = _zncc_direct(ref, warped, r, 0.5)
    fin = np.isfinite(want)
    assert (np.isfinite(got) == fin).all()
    np.testing.assert_allclose(got[fin], want[fin], atol=2e-4)
    if r > 0:
        assert np.allclose(got[3:, 3:, 1], 0.0, atol=1e-4)  # gain 0.5 and offset 20 do not matter


def test_zncc_cost_ignores_gain_and_offset_and_marks_missing_views():
    rng = np.random.default_rng(3)
    ref = rng.uniform(0, 255, (12, 12)).astype(np.float32)
    shifted = np.stack([np.roll(ref, d, axis=1) for d in range(-2, 3)], 2)  # plane 2 is the true one
    c1 = costs.zncc_cost(ref, shifted, 2, 1.0)
    c2 = costs.zncc_cost(ref, 1.7 * shifted - 40.0, 2, 1.0)
    np.testing.assert_allclose(c1, c2, atol=1e-4)
    best, _, _ = costs.winner(c1[:, 3:-3])
    assert (best == 2).all()
    valid = np.ones(shifted.shape, bool)
    valid[5, 5, 2] = False
    c3 = costs.zncc_cost(ref, shifted, 2, 1.0, valid)
    assert c3[5, 5, 2] == 1.0 and c3[5, 6, 2] == pytest.approx(0.0, abs=1e-4)


def test_best_k_mean():
    rng = np.random.default_rng(4)
    v = rng.uniform(0, 2, (6, 3, 4, 5)).astype(np.float32)
    for k in (1, 3, 6, 9):
        want = np.sort(v, axis=0)[:min(k, 6)].mean(axis=0)
        np.testing.assert_allclose(costs.best_k_mean(v, k), want, rtol=1e-6)
    v[:, 0, 0, 0] = np.inf
    assert np.isinf(costs.best_k_mean(v, 2)[0, 0, 0])
    with pytest.raises(ValueError):
        costs.best_k_mean(v, 0)

