"""Bjøntegaard deltas through the ``bjontegaard`` package, checked on published curve pairs."""
import math

import numpy as np
import pytest

pytest.importorskip("bjontegaard")

from benchmarks.bd import bd_pair, bd_psnr, bd_rate, psnr_overlap  # noqa: E402

# "Sample 1" shipped with the public VCEG-M33 reference scripts (rates kbit/s, PSNR dB).
R1, P1 = [686.76, 309.58, 157.11, 85.95], [40.28, 37.18, 34.24, 31.42]
R2, P2 = [893.34, 407.8, 204.93, 112.75], [40.39, 37.21, 34.17, 31.24]
# "Test 1" of the FAU-LMS bjontegaard package's README (libx265 presets).
RA, PA = [9487.76, 4593.60, 2486.44, 1358.24], [40.037, 38.615, 36.845, 34.851]
RT, PT = [9787.80, 4469.00, 2451.52, 1356.24], [40.121, 38.651, 36.970, 34.987]


def vceg_m33_rate(r1, p1, r2, p2) -> float:
    """VCEG-M33 evaluated independently: cubic fit of ln(rate) on PSNR, integrated over the overlap."""
    c1, c2 = np.polyfit(p1, np.log(r1), 3), np.polyfit(p2, np.log(r2), 3)
    lo, hi = max(min(p1), min(p2)), min(max(p1), max(p2))
    i1, i2 = np.polyint(c1), np.polyint(c2)
    diff = ((np.polyval(i2, hi) - np.polyval(i2, lo)) - (np.polyval(i1, hi) - np.polyval(i1, lo))) / (hi - lo)
    return (math.exp(diff) - 1) * 100


def test_cubic_bd_rate_matches_the_published_vceg_m33_sample():
    assert bd_rate(R1, P1, R2, P2, "cubic") == pytest.approx(31.397374054908013, abs=1e-6)
    assert bd_rate(R1, P1, R2, P2, "cubic") == pytest.approx(vceg_m33_rate(R1, P1, R2, P2), abs=1e-6)


def test_fau_readme_example():
    assert bd_rate(RA, PA, RT, PT, "cubic") == pytest.approx(-4.420462706090111, abs=1e-6)
    assert bd_rate(RA, PA, RT, PT, "cubic") == pytest.approx(vceg_m33_rate(RA, PA, RT, PT), abs=1e-6)
    # PCHIP (the CTC spreadsheet's interpolation) agrees within a few hundredths on these smooth curves
    assert bd_rate(RA, PA, RT, PT, "pchip") == pytest.approx(-4.42, abs=0.05)
    assert bd_psnr(RA, PA, RT, PT, "pchip") == pytest.approx(0.12, abs=0.01)


@pytest.mark.parametrize("method", ["pchip", "cubic"])
def test_exact_answers_for_scaled_and_shifted_curves(method):
    assert bd_rate(R1, P1, [r * 1.25 for r in R1], P1, method) == pytest.approx(25.0, abs=1e-9)
    assert bd_rate(R1, P1, R1, P1, method) == pytest.approx(0.0, abs=1e-12)
    assert bd_psnr(R1, P1, R1, [p + 0.5 for p in P1], method) == pytest.approx(0.5, abs=1e-9)


def test_no_psnr_overlap_gives_nan_and_the_overlap_is_reported():
    far = [p + 20 for p in P1]
    assert math.isnan(bd_rate(R1, P1, R1, far))
    fig = bd_pair(R1, P1, R1, far)
    assert fig["overlap"] == 0.0 and fig["psnr_pchip"] == pytest.approx(20.0)
    assert psnr_overlap(P1, P1) == 1.0
    assert psnr_overlap([30, 32, 34, 36], [34, 36, 38, 40]) == pytest.approx(0.2)


def test_bad_curves_are_refused():
    with pytest.raises(ValueError, match="at least 4"):
        bd_rate(R1[:3], P1[:3], R2[:3], P2[:3])
    with pytest.raises(ValueError, match="positive"):
        bd_rate([0, *R1[1:]], P1, R2, P2)
    with pytest.raises(ValueError, match="interpolation"):
        bd_rate(R1, P1, R2, P2, "akima-ish")
