"""Parameters of a drone reconstruction (the ``reconstruction`` job and the CLI verb).

The web layer validates request parameters with :class:`ReconstructionParams`; checks that need
the media (intrinsics against the image size, enough frames) happen in the job.
"""
from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from workers.settings import worker_settings

_DIST_LENGTHS = (4, 5, 8, 12, 14)


def max_dense_volume_from_env() -> int:
    """Most cost-volume cells (depth-map pixels x planes) a dense pass with ``dense_aggregation: "sgm"``
    may hold at once: ``$SWEEPCAST_MAX_DENSE_VOLUME``, else 300,000,000 (about 1.2 GB of float32, twice
    that while aggregating). The streamed ``window`` aggregation holds no volume and has no such limit."""
    return worker_settings().max_dense_volume


class ReconstructionParams(BaseModel):
    """Settings of one reconstruction. Pixel values refer to the media's native resolution
    (intrinsics) or to the working resolution after ``max_width`` (thresholds)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)  # NaN/Infinity: never a valid value

    fx: float | None = Field(None, gt=0, description="Focal length x, pixels (native resolution).")
    fy: float | None = Field(None, gt=0, description="Focal length y, pixels (native resolution).")
    cx: float | None = Field(None, description="Principal point x, pixels; (0, 0) = centre of the top-left pixel.")
    cy: float | None = Field(None, description="Principal point y, pixels.")
    calibration: str | None = Field(
        None, max_length=100_000,
        description="Text of a calibration file (OpenCV YAML/XML/JSON, COLMAP cameras.txt, or 'fx fy cx cy'); "
                    "the job also accepts it as an input named 'calibration'.")
    distortion: list[float] | None = Field(
        None, description="OpenCV distortion coefficients k1 k2 p1 p2 [k3 ...]; frames are undistorted first.")

    refine_intrinsics: bool | None = Field(
        None, description="Self-calibration: refine the focal length, radial distortion (k1, k2) and principal "
                          "point, shared by every frame, in bundle adjustment. Default: when no intrinsics are given (they then start from "
                          "the photos' EXIF, the video's DJI telemetry or a 72 degree field of view; the focal length "
                          "moves only where the images determine it); given intrinsics are used as they are.")

    georeference: Literal["auto", "required", "off"] = Field(
        "auto", description="Place the result in the world (the local UTM zone) from the frames' GPS positions "
                            "(stills: EXIF; video: DJI .SRT telemetry, uploaded as 'telemetry' or in the video's "
                            "subtitle stream): 'auto' when there are any, 'required' fails without them, 'off' keeps "
                            "the reconstruction's own frame.")
    gps_prior_m: float | None = Field(
        None, gt=0, le=1000,
        description="After georeferencing, a bundle adjustment with the GPS positions as a prior on the camera "
                    "centres of this standard deviation (metres per axis); None: the similarity fit alone.")
    orthophoto: bool | None = Field(
        None, description="orthophoto.tif (Cloud-Optimized GeoTIFF, RGBA, transparent outside the flight) and "
                          "orthophoto.png; runs the dense pass. Default: on for a georeferenced flight.")
    dsm: bool | None = Field(
        None, description="dsm.tif (float32 heights in metres, the orthophoto's grid) and dsm.png; runs the dense "
                          "pass. Default: on for a georeferenced flight.")
    gsd_cm: float | None = Field(
        None, gt=0, le=100_000,
        description="Ground sampling distance of the orthophoto, centimetres per pixel (georeferenced flights); "
                    "default: the photos' own (a native pixel straight below the camera at the median depth). The "
                    "DSM's cell is the depth maps' own, a whole multiple of it, never finer; report.json -> mapping "
                    "says what was chosen and why.")

    frame_step: int | None = Field(None, ge=1, le=10_000,
                                   description="Use every k-th frame; None selects frames adaptively by motion.")
    min_motion: float = Field(0.004, ge=0, le=0.5,
                              description="Adaptive selection: image motion (fraction of the width) between frames.")
    blur_ratio: float = Field(0.5, ge=0, lt=1,
                              description="Skip a frame whose Laplacian variance is below this fraction of the "
                                          "recent median (0 keeps all).")
    max_frames: int = Field(400, ge=2, le=5000, description="Video: most frames tracked; the step grows to fit "
                                                            "(stills: every photo is used, however many).")
    max_width: int = Field(1280, ge=160, le=8192, description="Frames wider than this are downscaled for tracking and "
                                                              "depth maps (the orthophoto samples the photos at their "
                                                              "own resolution).")
    submodel_photos: int = Field(
        150, ge=4, le=100_000,
        description="Stills with GPS: a survey of more photos is split by position into overlapping submodels of "
                    "about this many, each reconstructed on its own (across the cluster) and merged by the photos they "
                    "share and the GPS.")
    submodel_overlap_m: float | None = Field(
        None, gt=0, le=100_000,
        description="Stills with GPS: every photo within this distance (metres) of a submodel's own photos joins it; "
                    "default: 1.15 times the median distance from a photo to its 6th nearest (in a lawnmower survey: the "
                    "next flight line and the next photos along it).")

    matcher: Literal["fast_lk", "sift"] = Field("fast_lk", description="FAST + optical flow (the paper) or SIFT.")
    fast_threshold: int = Field(20, ge=1, le=255,
                                description="FAST intensity threshold; halved (down to 5) while a frame has fewer "
                                            "than 2 x max_features corners.")
    max_features: int = Field(2000, ge=50, le=20_000, description="Tracked features per frame (SIFT: x2).")
    feature_spacing: float = Field(8.0, ge=1, le=200, description="Minimum distance between features, pixels.")
    outlier_threshold: float = Field(2.0, gt=0, le=50,
                                     description="The paper's rule: flow end point to nearest FAST corner, pixels.")
    max_track_gap: int = Field(4, ge=0, le=50,
                               description="Frames in a row a track may fail the paper's rule (its flow otherwise "
                                           "consistent) and still go on; 0 ends it at the first failure.")
    fb_threshold: float = Field(1.0, gt=0, le=50, description="Forward-backward flow error limit, pixels.")
    ransac_threshold: float = Field(1.0, gt=0, le=50, description="Epipolar distance for RANSAC on E, pixels.")
    lk_window: int = Field(21, ge=5, le=101, description="Lucas-Kanade window size, pixels.")
    lk_levels: int = Field(4, ge=0, le=8, description="Lucas-Kanade pyramid levels.")
    sift_ratio: float = Field(0.8, gt=0, lt=1, description="Lowe's ratio test.")
    match_window: int = Field(2, ge=1, le=20, description="SIFT: match each frame with this many following ones.")

    keyframe_parallax: float = Field(0.02, ge=0, le=1,
                                     description="New keyframe when tracks moved this fraction of the width.")
    min_triangulation_angle: float = Field(1.5, gt=0, le=45, description="Degrees.")
    reprojection_threshold: float = Field(4.0, gt=0, le=100, description="Observations above are outliers, pixels.")
    ba_loss: Literal["trivial", "huber", "cauchy"] = "cauchy"
    ba_loss_scale: float = Field(2.0, gt=0, le=100, description="Robust loss scale, pixels.")
    ba_iterations: int = Field(50, ge=1, le=1000, description="LM iterations of each global adjustment.")
    joint_ba: bool = Field(True, description="After the selected non-keyframes are registered by PnP, a final "
                                             "bundle adjustment refines them with the keyframes and points, their "
                                             "tracked observations included.")

    dense: bool = Field(False, description="After the sparse model, a dense pass: a depth map per reference frame "
                                           "(plane sweep, ZNCC), fused into dense.ply (points, normals, colours).")
    dense_frames: int | None = Field(
        None, ge=2, le=1_000_000,
        description="Dense: a depth map for this many registered frames, spread evenly (the others are then not in "
                    "the dense cloud, and report.json -> dense says so); default: every registered frame.")
    dense_neighbours: int = Field(8, ge=1, le=16, description="Dense: neighbours swept against each reference.")
    dense_best_k: int = Field(4, ge=1, le=16,
                              description="Dense: a plane's cost is the mean over the best k neighbours (occlusions).")
    dense_planes: int = Field(128, ge=4, le=512, description="Dense: depth planes, uniform in inverse depth.")
    dense_window: int = Field(5, ge=1, le=15, description="Dense: ZNCC window side, pixels (odd).")
    dense_scale: float = Field(1.0, gt=0, le=1,
                               description="Dense: depth-map resolution as a fraction of the working resolution.")
    dense_min_texture: float = Field(1.5, ge=0, le=64,
                                     description="Dense: grey-level standard deviation a window needs to be matched.")
    dense_max_cost: float = Field(0.5, gt=0, le=2, description="Dense: largest accepted cost (mean 1 - ZNCC).")
    dense_aggregation: Literal["window", "sgm"] = Field(
        "window", description="Dense: 'window' (ZNCC window alone, streamed) or 'sgm' (+ semi-global smoothing; "
                              "slower, holds a cost volume).")
    dense_coarse_to_fine: bool = Field(True, description="Dense: sweep all planes at half resolution, then only "
                                                         "those near the coarse depth at full resolution.")
    dense_min_views: int = Field(3, ge=1, le=17,
                                 description="Dense: frames (the reference included) that must agree on a point.")
    dense_max_reprojection: float = Field(1.0, gt=0, le=20,
                                          description="Dense: consistency, reprojection error limit, pixels.")
    dense_max_depth_error: float = Field(0.01, gt=0, le=0.5,
                                         description="Dense: consistency, relative depth difference limit.")

    @model_validator(mode="after")
    def _check(self) -> "ReconstructionParams":
        given = [v is not None for v in (self.fx, self.fy, self.cx, self.cy)]
        if any(given) and not all(given):
            raise ValueError("give all four of fx, fy, cx, cy (or a calibration)")
        if self.distortion is not None and len(self.distortion) not in _DIST_LENGTHS:
            raise ValueError(f"distortion needs {', '.join(map(str, _DIST_LENGTHS))} coefficients, "
                             f"got {len(self.distortion)}")
        if self.refine_intrinsics and self.distortion is not None:
            raise ValueError("refine_intrinsics refines its own radial distortion: leave out 'distortion'")
        if self.gsd_cm is not None and self.georeference == "off":
            raise ValueError("gsd_cm is in centimetres on the ground: it needs georeference 'auto' or 'required'")
        if self.dense_window % 2 == 0:
            raise ValueError(f"dense_window must be odd, got {self.dense_window}")
        if self.dense_best_k > self.dense_neighbours:
            raise ValueError(f"dense_best_k ({self.dense_best_k}) cannot exceed dense_neighbours "
                             f"({self.dense_neighbours})")
        if self.dense_min_views > self.dense_neighbours + 1:
            raise ValueError(f"dense_min_views ({self.dense_min_views}) cannot exceed dense_neighbours + 1 "
                             f"({self.dense_neighbours + 1})")
        return self
