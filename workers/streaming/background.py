"""The background model of a live stream: one empty-scene image per camera, for the silhouettes."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from workers.sweep.silhouette import silhouette_from_background


class BackgroundModel:
    """Per-camera empty-scene images of a live rig, and the silhouettes of new frames against them.

    Frame sets flagged as background (the studio without its subject) set the model; consecutive
    flagged sets are averaged. Afterwards each frame updates the model where it shows background
    (a selective running average with weight ``rate``), so slow light changes are followed while the
    subject is never absorbed. Without any flagged set there is no model and no silhouettes.
    threshold: largest channel difference (0..255) above which a pixel is foreground.
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
        """The model, (H, W, 3) uint8 BGR per camera; empty list when not ready."""
        return [] if self._model is None else [np.clip(m + 0.5, 0, 255).astype(np.uint8) for m in self._model]

    def load(self, images: Sequence[np.ndarray]) -> None:
        """Set the model from stored images (H, W, 3) uint8, one per camera."""
        self._check(images)
        self._model = [np.asarray(i, np.float32) for i in images]
        self._flagged_run = 0

    def observe(self, images: Sequence[np.ndarray], is_background: bool) -> list[np.ndarray] | None:
        """Take a new frame set (one (H, W, 3) uint8 image per camera); return its silhouettes
        ((H, W) bool per camera), or None while there is no model."""
        self._check(images)
        if is_background:
            self._flagged_run += 1
            if self._model is None or self._flagged_run == 1:
                self._model = [np.asarray(i, np.float32) for i in images]
            else:
                w = 1.0 / self._flagged_run
                self._model = [(1 - w) * m + w * i.astype(np.float32) for m, i in zip(self._model, images)]
            return [np.zeros(i.shape[:2], bool) for i in images]
        self._flagged_run = 0
        if self._model is None:
            return None
        silhouettes = []
        for m, img in zip(self._model, images):
            sil = silhouette_from_background(img, np.clip(m + 0.5, 0, 255).astype(np.uint8), self.threshold)
            bg = ~sil
            m[bg] += self.rate * (img[bg].astype(np.float32) - m[bg])
            silhouettes.append(sil)
        return silhouettes

    def _check(self, images: Sequence[np.ndarray]) -> None:
        if len(images) != self.n:
            raise ValueError(f"{len(images)} images for {self.n} cameras")
