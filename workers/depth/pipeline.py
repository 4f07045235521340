"""Frame-rate decoding side: upsample + post-filter frames of one size with reused buffers.

Gives the same output as :func:`methods.postprocess` but allocates its images once: at 1920x1088
a fresh 2 MB array per OpenCV call costs about as much in page faults as the 3x3 filter itself.
Guided methods ("wmf")
and the Otsu rule fall back to the allocating path.
"""
from __future__ import annotations

import cv2
import numpy as np

from .errors import DepthInputError
from .filters import MORPH_ORDERS, check_window
from .levels import check_levels, level_dtype, max_level
from .methods import FilterOptions, apply_method, check_method
from .upsample import UPSAMPLERS


class FramePipeline:
    """Upsample and filter (H, W) frames to (out_h, out_w) with one method and fixed options.

    ``pipeline(frame, guide=None)`` returns (out_h, out_w) levels of the frame's dtype. The result
    is a buffer reused by the next call: copy it to keep it. ``upsampled`` holds the last frame
    after upsampling, before filtering.
    """

    def __init__(
        self, in_shape: tuple[int, int], out_size: tuple[int, int], method: str, upsampler: str = "nearest",
        options: FilterOptions = FilterOptions(),
    ) -> None:
        check_method(method)
        if upsampler not in UPSAMPLERS:
            raise DepthInputError(f"unknown upsampler {upsampler!r}; expected one of {', '.join(UPSAMPLERS)}")
        if options.morph_order not in MORPH_ORDERS:
            raise DepthInputError(f"unknown morphology order {options.morph_order!r}")
        self._fast = method in ("none", "dilation") or (
            method in ("modified", "modified_morph") and options.rule == "midrange"
        )
        self.in_shape, self.out_size, self.method, self.options = tuple(in_shape), tuple(out_size), method, options
        self._interp = UPSAMPLERS[upsampler]
        self._kernel = np.ones((check_window(options.window),) * 2, np.uint8)
        self._morph_kernel = np.ones((check_window(options.morph_window, "morph_window"),) * 2, np.uint8)
        w, h = self.out_size
        dtype = level_dtype(options.bits)
        names = ["up", "hi", "lo", "a", "b", "out", "tmp"] + ([] if options.larger_is_nearer else ["flip"])
        self._buf = {name: np.empty((h, w), dtype) for name in names}
        self._mask = np.empty((h, w), np.uint8)
        self._mask2 = np.empty((h, w), np.uint8)

    def __call__(self, frame: np.ndarray, guide: np.ndarray | None = None) -> np.ndarray:
        check_levels(frame, self.options.bits)
        if frame.shape != self.in_shape:
            raise DepthInputError(
                f"frame is {frame.shape[1]}x{frame.shape[0]}, expected {self.in_shape[1]}x{self.in_shape[0]}"
            )
        up = self._buf["up"]
        if frame.shape == up.shape:
            np.copyto(up, frame)
        else:
            cv2.resize(frame, self.out_size, dst=up, interpolation=self._interp)
        if not self._fast:
            return apply_method(up, self.method, guide, self.options)
        if self.method == "none":
            return up
        if self.options.larger_is_nearer:
            return self._filter(up)
        top = max_level(self.options.bits)
        out = self._filter(cv2.subtract(top, up, dst=self._buf["flip"]))
        return cv2.subtract(top, out, dst=out)

    @property
    def upsampled(self) -> np.ndarray:
        """The last frame after upsampling (a reused buffer)."""
        return self._buf["up"]

    def _filter(self, up: np.ndarray) -> np.ndarray:
        """The dilation family on the upsampled frame; returns one of the buffers."""
        b, k = self._buf, self._kernel
        cv2.dilate(up, k, dst=b["hi"])
        if self.method == "dilation":
            return b["hi"]
        cv2.erode(up, k, dst=b["lo"])
        cv2.subtract(up, b["lo"], dst=b["a"])  # distance to the window minimum
        cv2.subtract(b["hi"], up, dst=b["b"])  # distance to the window maximum
        cv2.compare(b["a"], b["b"], cv2.CMP_GT, dst=self._mask)  # nearer the maximum: foreground
        if self.options.min_contrast > 0:
            cv2.subtract(b["hi"], b["lo"], dst=b["a"])
            cv2.compare(b["a"], float(self.options.min_contrast), cv2.CMP_GE, dst=self._mask2)
            cv2.bitwise_and(self._mask, self._mask2, dst=self._mask)
        np.copyto(b["out"], up)
        cv2.copyTo(b["hi"], self._mask, dst=b["out"])
        if self.method == "modified":
            return b["out"]
        src, dst = b["out"], b["tmp"]
        for step in self.options.morph_order.split("-"):
            cv2.morphologyEx(src, cv2.MORPH_CLOSE if step == "close" else cv2.MORPH_OPEN, self._morph_kernel, dst=dst)
            src, dst = dst, src
        return src
