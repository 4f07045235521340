"""The background model of a live stream: one empty-scene image per camera, for the silhouettes."""
from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from workers.sweep.silhouette import silhouette_from_background


class BackgroundModel:
    """Per-camera empty-scene images of a live rig, and the silhouettes of new frames against them.

    Frame sets flagged as background (the studio without its subject) set the model; consecutive
    flagged sets are averaged. Afterwards each frame updates the model where it shows background
    (a selective running average with weight ``rate``), so slow light changes are followed while the
    subject is never absorbed. Without any flagged set there is no model and no silhouettes.
    threshold: largest channel difference (0..255) above which a pixel is foreground.
    The model has the size of the frames it is given (a live session works at a reduced size:
    :meth:`resize` follows it when that size changes).
    """

    def __init__(self, n_cameras: int, rate: float = 0.02, threshold: float = 20.0) -> None:
        self.n = n_cameras
        self.rate = float(rate)
        self.threshold = float(threshold)
        self._model: list[np.ndarray] | None = None
        self._flagged_run = 0

    @property
    def ready(self) -> bool:
        return self._model is not None

    def images(self) -> list[np.ndarray]:
        """The model, (H, W, 3) uint8 BGR per camera (rounded, saturated); empty list when not ready."""
        return [] if self._model is None else [cv2.convertScaleAbs(m) for m in self._model]

    def load(self, images: Sequence[np.ndarray], sizes: Sequence[tuple[int, int]] | None = None) -> None:
        """Set the model from stored images (H, W, 3) uint8, one per camera, resized to ``sizes``
        ((width, height) per camera) where given and different."""
        self._check(images)
        self._model = [np.asarray(i, np.float32) for i in images]
        self._flagged_run = 0
        if sizes is not None:
            self.resize(sizes)

    def resize(self, sizes: Sequence[tuple[int, int]]) -> None:
        """Resample the model to ``sizes`` ((width, height) per camera): area-averaged when it
        shrinks, bilinear when it grows (finer detail is then relearnt by the running average)."""
        if self._model is None:
            return
        out = []
        for m, (w, h) in zip(self._model, sizes):
            if m.shape[:2] != (h, w):
                shrink = w * h < m.shape[0] * m.shape[1]
                m = cv2.resize(m, (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
            out.append(m)
        self._model = out

    def observe(self, images: Sequence[np.ndarray], is_background: bool) -> list[np.ndarray] | None:
        """Take a new frame set (one (H, W, 3) uint8 image per camera, the model's size); return its
        silhouettes ((H, W) bool per camera), or None while there is no model."""
        self._check(images)
        if is_background:
            self._flagged_run += 1
            if self._model is None or self._flagged_run == 1:
                self._model = [np.asarray(i, np.float32) for i in images]
            else:
                w = 1.0 / self._flagged_run
                for m, i in zip(self._model, images):
                    cv2.accumulateWeighted(i, m, w)
            return [np.zeros(i.shape[:2], bool) for i in images]
        self._flagged_run = 0
        silhouettes = self.silhouettes(images)
        if silhouettes is not None:
            for m, img, sil in zip(self._model, images, silhouettes):
                # m += rate * (img - m) where the frame shows background, in place (OpenCV, one pass)
                cv2.accumulateWeighted(img, m, self.rate, mask=(~sil).view(np.uint8))
        return silhouettes

    def silhouettes(self, images: Sequence[np.ndarray]) -> list[np.ndarray] | None:
        """The silhouettes of a frame set ((H, W) bool per camera) without learning from it; None
        while there is no model."""
        self._check(images)
        if self._model is None:
            return None
        out = []
        for m, img in zip(self._model, images):
            if m.shape != img.shape:
                raise ValueError(f"frame {img.shape} and background model {m.shape} differ in shape")
            out.append(silhouette_from_background(img, cv2.convertScaleAbs(m), self.threshold))
        return out

    def _check(self, images: Sequence[np.ndarray]) -> None:
        if len(images) != self.n:
            raise ValueError(f"{len(images)} images for {self.n} cameras")
