"""A generated rectified two-layer scene with integer disparities, rendered exactly per view."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Scene:
    """Background plane (disparity ``d_bg``) and a foreground rectangle (``d_fg``), random textures.

    A view at camera position ``p`` (in reference baselines) sees canvas column ``u`` of a layer with
    disparity d at ``x = u - p * d`` (so x_target = x_source - shift * d, as in ``dibr``).
    """

    width: int = 64
    height: int = 40
    d_bg: int = 2
    d_fg: int = 8
    fg_x: tuple[int, int] = (24, 40)  # foreground columns [a, b) at p = 0
    fg_y: tuple[int, int] = (10, 30)
    seed: int = 0
    pad: int = 64

    def _textures(self) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng(self.seed)
        shape = (self.height, self.width + 2 * self.pad, 3)
        return rng.integers(0, 256, shape, dtype=np.uint8), rng.integers(0, 256, shape, dtype=np.uint8)

    def render(self, p: int) -> tuple[np.ndarray, np.ndarray]:
        """(texture (H, W, 3) uint8, disparity (H, W) float32) of the view at position p."""
        bg, fg = self._textures()
        x = np.arange(self.width)
        image = np.empty((self.height, self.width, 3), np.uint8)
        disp = np.full((self.height, self.width), self.d_bg, np.float32)
        image[:] = bg[:, x + p * self.d_bg + self.pad]
        u_fg = x + p * self.d_fg  # canvas column of the foreground layer seen at x
        cols = (u_fg >= self.fg_x[0]) & (u_fg < self.fg_x[1])
        rows = slice(*self.fg_y)
        image[rows, cols] = fg[rows, u_fg[cols] + self.pad]
        disp[rows, cols] = self.d_fg
        return image, disp

    def visible_from(self, p_src: int, p_dst: int) -> np.ndarray:
        """(H, W) bool: target pixels whose scene point the source view sees (inside its frame)."""
        _, disp_dst = self.render(p_dst)
        _, disp_src = self.render(p_src)
        x = np.arange(self.width)[None, :]
        xs = x + (p_dst - p_src) * disp_dst  # where the point is in the source view
        inside = (xs >= 0) & (xs < self.width)
        ys = np.arange(self.height)[:, None].repeat(self.width, 1)
        seen = np.zeros_like(inside)
        seen[inside] = disp_src[ys[inside], xs[inside].astype(int)] == disp_dst[inside]
        return seen
