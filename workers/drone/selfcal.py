"""Self-calibration without given intrinsics: where the focal length starts and how firmly it is held,
and the radial lens model the bundle adjustment refines (one camera for every frame, as COLMAP's
RADIAL camera: focal length ``f``, distortion ``k1, k2``; the principal point starts at the image centre and is
refined under a weak prior, :data:`workers.drone.reconstruction.CENTRE_PRIOR_SIGMA`).

The start, in order of trust:

1. EXIF focal length in mm and the sensor width from :data:`SENSOR_WIDTH_MM` (the camera's model);
2. EXIF ``FocalLengthIn35mmFilm``: the focal length that gives the same diagonal field of view on a
   36 x 24 mm frame (diagonal 43.27 mm);
3. EXIF focal length in mm and the focal-plane resolution (pixel pitch on the sensor);
4. a 35 mm equivalent from the drone's video telemetry (DJI ``focal_len``);
5. a default horizontal field of view (video carries no EXIF).

Each source comes with a prior's standard deviation (a fraction of the focal length): a flat scene
seen from straight above cannot tell a longer lens from a higher flight (the images change alike), and
the prior is what keeps the focal length where the camera says it is there.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .exif import PhotoMeta

DIAGONAL_35MM = math.hypot(36.0, 24.0)
DEFAULT_FOV_DEG = 72.0
"""Horizontal field of view assumed for media that say nothing about their lens (a typical drone camera)."""
DISTORTION_PRIOR_SIGMA = 0.25
"""Standard deviation of the zero-mean priors on k1 and k2: only keeps a badly constrained fit finite."""

SENSOR_WIDTH_MM = {
    # DJI camera models (EXIF Model) -> sensor width, mm. 1/2.3": 6.17; 1/2": 6.4; 1": 13.2; 4/3: 17.3.
    "FC350": 6.17, "FC300X": 6.17, "FC300S": 6.17, "FC300C": 6.17, "FC330": 6.17, "FC220": 6.17,
    "FC1102": 6.17, "FC2103": 6.17, "FC2204": 6.17, "FC7203": 6.17, "FC3170": 6.4,
    "FC6310": 13.2, "FC6310S": 13.2, "FC6310R": 13.2, "L1D-20C": 13.2, "FC3411": 13.2,
    "FC550": 17.3, "FC6520": 17.3,
}
_SIGMA = {"given": 0.05, "exif_sensor_table": 0.02, "exif_35mm": 0.03, "exif_focal_plane": 0.05, "telemetry_35mm": 0.10,
          "default_fov": 0.25}


@dataclass(frozen=True)
class FocalPrior:
    """A focal length to start from, in pixels of the media's native resolution, and the prior's
    standard deviation ``sigma`` as a fraction of it; ``source`` names where it came from (a key of the
    list in the module docstring), ``detail`` says it in words."""

    focal_px: float
    sigma: float
    source: str
    detail: str

    def scaled(self, s: float) -> "FocalPrior":
        """The same prior for the image resized by ``s``."""
        return FocalPrior(self.focal_px * s, self.sigma, self.source, self.detail)


def focal_from_35mm(focal_35mm: float, width: int, height: int) -> float:
    """Pixels for a 35 mm equivalent focal length (same diagonal field of view) of a width x height image."""
    return focal_35mm / DIAGONAL_35MM * math.hypot(width, height)


def focal_prior_from_exif(meta: PhotoMeta, width: int, height: int) -> FocalPrior | None:
    """The best focal length the EXIF of a width x height photo gives (sources 1-3), or None."""
    model = (meta.model or "").strip().upper()
    if meta.focal_mm and model in SENSOR_WIDTH_MM:
        sensor = SENSOR_WIDTH_MM[model]
        return _prior(meta.focal_mm / sensor * width, "exif_sensor_table",
                      f"EXIF focal length {meta.focal_mm:g} mm on the {model}'s {sensor:g} mm wide sensor")
    if meta.focal_35mm:
        return _prior(focal_from_35mm(meta.focal_35mm, width, height), "exif_35mm",
                      f"EXIF 35 mm equivalent focal length {meta.focal_35mm:g} mm")
    if meta.focal_mm and meta.focal_plane_mm_per_px:
        # The focal-plane resolution refers to the width the camera wrote (PixelXDimension).
        px_mm = meta.focal_plane_mm_per_px * (meta.exif_width or width) / width
        return _prior(meta.focal_mm / px_mm, "exif_focal_plane",
                      f"EXIF focal length {meta.focal_mm:g} mm and focal-plane resolution")
    return None


def focal_prior_from_telemetry(focal_35mm: float, width: int, height: int) -> FocalPrior:
    """Source 4: the 35 mm equivalent focal length a drone's telemetry gives for a video."""
    return _prior(focal_from_35mm(focal_35mm, width, height), "telemetry_35mm",
                  f"telemetry 35 mm equivalent focal length {focal_35mm:g} mm")


def given_focal_prior(focal_px: float) -> FocalPrior:
    """The user's own focal length as the start of self-calibration (``refine_intrinsics`` with given
    intrinsics)."""
    return _prior(focal_px, "given", f"the given focal length {focal_px:g} px")


def default_focal_prior(width: int, fov_deg: float = DEFAULT_FOV_DEG) -> FocalPrior:
    """Source 5: the focal length of a ``fov_deg`` horizontal field of view over ``width`` pixels."""
    return _prior(0.5 * width / math.tan(math.radians(fov_deg) / 2), "default_fov",
                  f"no EXIF: a default {fov_deg:g} degree horizontal field of view")


def _prior(focal_px: float, source: str, detail: str) -> FocalPrior:
    return FocalPrior(float(focal_px), _SIGMA[source], source, detail)


# ---------------------------------------------------------------------------------------------
# The radial lens model on pixels
# ---------------------------------------------------------------------------------------------
def distort_pixels(xy: np.ndarray, f: float, k1: float, k2: float, centre: np.ndarray) -> np.ndarray:
    """Ideal pinhole pixels (N, 2) -> the pixels the lens shows: ``c + f x (1 + k1 r^2 + k2 r^4)`` with
    ``x = (xy - c) / f``, ``r = |x|`` (OpenCV's radial model, k1 k2 only). float64 (N, 2)."""
    x = (np.asarray(xy, np.float64) - centre) / f
    r2 = (x * x).sum(axis=1, keepdims=True)
    return centre + f * x * (1.0 + r2 * (k1 + k2 * r2))


def undistort_pixels(xy: np.ndarray, f: float, k1: float, k2: float, centre: np.ndarray,
                     iterations: int = 20) -> np.ndarray:
    """The inverse of :func:`distort_pixels`: the lens's pixels (N, 2) -> ideal pinhole pixels (N, 2)
    float64, by Newton's method on the radius (exact to ~1e-12 px inside the lens's monotonic range)."""
    xy = np.asarray(xy, np.float64)
    if k1 == 0.0 and k2 == 0.0:
        return xy.copy()
    xd = (xy - centre) / f
    rd = np.sqrt((xd * xd).sum(axis=1))
    ru = rd.copy()
    for _ in range(iterations):
        r2 = ru * ru
        g = ru * (1.0 + r2 * (k1 + k2 * r2)) - rd
        dg = 1.0 + r2 * (3.0 * k1 + 5.0 * k2 * r2)
        ru = ru - g / np.where(np.abs(dg) > 1e-12, dg, 1e-12)
    scale = np.where(rd > 1e-15, ru / np.maximum(rd, 1e-15), 1.0)
    return centre + f * xd * scale[:, None]
