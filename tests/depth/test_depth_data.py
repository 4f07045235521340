"""Checks on the real Middlebury views (skipped when the benchmark data is absent)."""
import cv2
import numpy as np
import pytest

from workers.common.datasets import dataset
from workers.common.imagemetrics import psnr
from workers.depth import dibr

TEDDY = dataset("multiview", "teddy")


@pytest.mark.data
@pytest.mark.skipif(TEDDY is None, reason="Middlebury Teddy not in $SWEEPCAST_DATA")
def test_teddy_middle_view_from_ground_truth_disparity():
    views = [cv2.imread(str(TEDDY / f"im{k}.png")) for k in (2, 4, 6)]
    disps = []
    for name in ("disp2.pgm", "disp6.pgm"):
        raw = cv2.imread(str(TEDDY / name), cv2.IMREAD_UNCHANGED).astype(np.float32)
        disps.append(np.where(raw > 0, raw / 4, np.nan).astype(np.float32))  # quarter-pixel, 0 = unknown
    syn = dibr.synthesize_rectified([views[0], views[2]], disps, [0.5, -0.5])
    # NOTES.md anchor: a simple forward warp reaches 29.3 dB; copying the nearest view 16.9 dB
    assert psnr(syn.image, views[1]) > 29.3
    assert syn.holes.mean() < 0.05
