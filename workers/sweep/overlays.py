"""Pictures of a render's depth map and region map (as in the paper's Fig. 4(b) and 5(e))."""
from __future__ import annotations

import cv2
import numpy as np

# distinct BGR colours for cameras' one-camera regions (cycled when there are more cameras)
PALETTE = np.array([
    (80, 220, 250), (200, 130, 255), (255, 180, 90), (120, 230, 120), (90, 120, 255),
    (230, 230, 100), (255, 120, 200), (160, 160, 255), (100, 200, 200), (200, 200, 200),
], np.uint8)
EMPTY_COLOR = (255, 255, 255)
BLEND_COLOR = (0, 0, 0)  # two cameras blended
BLEND3_COLOR = (0, 0, 230)  # three or more cameras blended (red; no camera colour is a saturated red)


def regions_image(regions: np.ndarray, primary: np.ndarray) -> np.ndarray:
    """(h, w, 3) uint8 BGR coloured by the number of cameras blended: one-camera regions in a colour
    per camera (its ``primary`` index), two-camera regions black, regions blending three or more
    cameras (kojima_k near the junctions of three one-camera regions, ulr with k >= 3) red, pixels
    without a surface white.

    regions (h, w) uint8 and primary (h, w) int16 as in :class:`RenderResult`."""
    out = PALETTE[np.maximum(primary, 0) % len(PALETTE)].copy()
    out[regions == 2] = BLEND_COLOR
    out[regions >= 3] = BLEND3_COLOR
    out[regions == 0] = EMPTY_COLOR
    return out


def depth_image(depth: np.ndarray) -> np.ndarray:
    """(h, w, 3) uint8 BGR picture of a depth map (h, w) (inverse depth through OpenCV's TURBO
    colour map, near = warm); pixels without depth (inf) are black."""
    ok = np.isfinite(depth) & (depth > 0)
    out = np.zeros(depth.shape + (3,), np.uint8)
    if not ok.any():
        return out
    inv = np.zeros(depth.shape, np.float64)
    inv[ok] = 1.0 / depth[ok]
    lo, hi = inv[ok].min(), inv[ok].max()
    scaled = np.zeros(depth.shape, np.uint8)
    scaled[ok] = np.round(255 * (inv[ok] - lo) / (hi - lo if hi > lo else 1.0)).astype(np.uint8)
    out[ok] = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)[ok]
    return out
