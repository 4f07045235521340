"""The three post-filters of Lee, Yang & Oh (dilation, modified dilation, + morphology).

All work on depth levels where larger = nearer (foreground is bright); callers with the opposite
convention flip first (see ``methods``). Inputs and outputs are (H, W) uint8 or uint16, same dtype;
``window`` is the side of the square neighbourhood N(k) (odd, in pixels).

Foreground/background classification (section II-B): inside each window the levels are split into
two clusters and pixel k is foreground when it falls in the upper (nearer) cluster. Two rules:

- ``"midrange"`` (default): k is foreground when it is strictly closer to the window's maximum than
  to its minimum. This is the split 2-means makes with its two centres at the window's extremes;
  for an edge blurred by upsampling or coding, the extremes are the two plateaus, so it is the
  right split there, and it costs one ``cv2.dilate`` and one ``cv2.erode``.
- ``"otsu"``: the exact two-cluster split of the window's values (Otsu's threshold, i.e. the
  optimal 1-D 2-means partition), slower; kept to check that the cheap rule loses nothing.

``min_contrast`` (levels) declares windows whose range is below it single-cluster: nothing there is
foreground, so noise in flat areas is not dilated.
"""
from __future__ import annotations

import cv2
import numba
import numpy as np

from .errors import DepthInputError

CLASSIFY_RULES = ("midrange", "otsu")
MORPH_ORDERS = ("close", "open", "close-open", "open-close")
MAX_WINDOW = 31


def check_window(window: int, name: str = "window") -> int:
    """``window`` as an odd int in [1, 31]; raises DepthInputError otherwise."""
    if not isinstance(window, (int, np.integer)) or window < 1 or window > MAX_WINDOW or window % 2 == 0:
        raise DepthInputError(f"{name} must be an odd integer from 1 to {MAX_WINDOW}, got {window!r}")
    return int(window)


def _kernel(window: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_RECT, (check_window(window), check_window(window)))


def dilation(depth: np.ndarray, window: int = 3) -> np.ndarray:
    """Eq. 1: ``D~_k = max(D_j), j in N(k)`` with N(k) the window x window square around k."""
    return cv2.dilate(depth, _kernel(window))


def classify_foreground(
    depth: np.ndarray, window: int = 3, rule: str = "midrange", min_contrast: int = 0
) -> np.ndarray:
    """Foreground mask (H, W) bool: pixels in the nearer of the two clusters of their window.

    depth: (H, W) uint8/uint16 levels. rule: "midrange" or "otsu" (module docstring).
    min_contrast: windows whose max - min is below it have no foreground.
    """
    return _foreground_mask(depth, window, rule, min_contrast) > 0


def _foreground_mask(depth: np.ndarray, window: int, rule: str, min_contrast: int) -> np.ndarray:
    """classify_foreground as an OpenCV mask: (H, W) uint8, 255 = foreground."""
    if rule not in CLASSIFY_RULES:
        raise DepthInputError(f"unknown classification rule {rule!r}; expected one of {', '.join(CLASSIFY_RULES)}")
    k = _kernel(window)
    hi, lo = cv2.dilate(depth, k), cv2.erode(depth, k)
    if rule == "midrange":
        fg = cv2.compare(cv2.subtract(depth, lo), cv2.subtract(hi, depth), cv2.CMP_GT)
    else:
        fg = _otsu_foreground(depth, window // 2).view(np.uint8) * np.uint8(255)
    if min_contrast > 0:
        edge = cv2.compare(cv2.subtract(hi, lo), float(min_contrast), cv2.CMP_GE)
        fg = cv2.bitwise_and(fg, edge)
    return fg


def modified_dilation(
    depth: np.ndarray, window: int = 3, rule: str = "midrange", min_contrast: int = 0
) -> np.ndarray:
    """Section II-B: dilate only the foreground; background pixels keep their level.

    Foreground pixel k becomes ``max(D_j), j in N(k)`` (eq. 1); every other pixel is unchanged, so
    a background pixel never takes a foreground value. Returns (H, W), same dtype.
    """
    fg = _foreground_mask(depth, window, rule, min_contrast)
    return cv2.copyTo(cv2.dilate(depth, _kernel(window)), fg, depth.copy())


def morphological_cleanup(depth: np.ndarray, window: int = 3, order: str = "close") -> np.ndarray:
    """Section II-C: grey-scale dilation and erosion that remove isolated classification errors.

    order: "close" (dilation then erosion, the paper's order: fills dark specks narrower than the
    window), "open" (erosion then dilation: removes bright specks), or the two in sequence
    ("close-open", "open-close"). Returns (H, W), same dtype.
    """
    if order not in MORPH_ORDERS:
        raise DepthInputError(f"unknown morphology order {order!r}; expected one of {', '.join(MORPH_ORDERS)}")
    k = _kernel(window)
    out = depth
    for step in order.split("-"):
        out = cv2.morphologyEx(out, cv2.MORPH_CLOSE if step == "close" else cv2.MORPH_OPEN, k)
    return out


def modified_dilation_morph(
    depth: np.ndarray, window: int = 3, rule: str = "midrange", min_contrast: int = 0,
    morph_window: int = 3, order: str = "close",
) -> np.ndarray:
    """Modified dilation followed by the morphological clean-up (the paper's full method)."""
    return morphological_cleanup(modified_dilation(depth, window, rule, min_contrast), morph_window, order)


@numba.njit(parallel=True, cache=True)
def _otsu_foreground(depth: np.ndarray, radius: int) -> np.ndarray:
    """Per-window Otsu split: True where the pixel is in the upper cluster of its window."""
    h, w = depth.shape
    out = np.zeros((h, w), np.bool_)
    n_max = (2 * radius + 1) ** 2
    for y in numba.prange(h):
        buf = np.empty(n_max, np.float64)
        for x in range(w):
            n = 0
            for yy in range(max(0, y - radius), min(h, y + radius + 1)):
                for xx in range(max(0, x - radius), min(w, x + radius + 1)):
                    v = float(depth[yy, xx])
                    i = n
                    while i > 0 and buf[i - 1] > v:  # insertion sort: windows are small
                        buf[i] = buf[i - 1]
                        i -= 1
                    buf[i] = v
                    n += 1
            total = 0.0
            for i in range(n):
                total += buf[i]
            best, thresh, below = 0.0, np.inf, 0.0
            for k in range(1, n):
                below += buf[k - 1]
                if buf[k - 1] == buf[k]:
                    continue
                m0 = below / k
                m1 = (total - below) / (n - k)
                score = k * (n - k) * (m1 - m0) ** 2
                if score > best:
                    best, thresh = score, buf[k]
            out[y, x] = depth[y, x] >= thresh
    return out
