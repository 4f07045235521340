"""The plane-sweep virtual-view renderer (Kojima & Fujimoto, section III), built once per rig and
frame set, then rendered many times per second from any viewpoint.

    r = SweepRenderer(rig, images, backgrounds=empty_views)   # or silhouettes=..., or neither
    out = r.render(virtual_camera, method="kojima", planes=48, near=1.5, far=4.0)  # D_bnd from the rig
    out.image, out.depth, out.regions, out.primary, out.timings

For a live stream call :meth:`SweepRenderer.set_frames` with each new synchronised frame set; the
geometry and buffers are kept.
"""
from __future__ import annotations

import logging
import os
import time
from contextlib import nullcontext
from dataclasses import dataclass, field, replace
from typing import Literal, Sequence

import numba
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from workers.camera import Camera
from workers.settings import worker_settings

from . import costs, kernels
from .lanes import lane_cost_volume
from .occlusion import background_fill, confirmed_views, fill_along_rows
from .rig import Rig, RigError
from .silhouette import BG_THRESHOLD, HULL_DILATE_PX, dilate, silhouette_box, silhouette_from_background
from .temporal import ChangeTracker
from .undistort import undistort_maps, undistorted
from .visibility import ZBufferStore, surface_zbuffers
from .weighting import METHOD_CODES, global_camera, neighbour_angle, suggest_d_bnd

log = logging.getLogger(__name__)

MAX_PLANES = 1024
MAX_VIEW_PIXELS = 4096 * 4096
BAND_ROWS = 16  # rows per work item of the sweep kernel (the pixel above seeds the search within a band)
REFINE_RADIUS = 1  # after a coarse level, a fine pixel's planes span the coarse choices of the 3 x 3 around its parent


class RenderOptions(BaseModel):
    """Per-call rendering options (validated; the service validates requests with this model).

    method: colour weighting (see :mod:`workers.sweep.weighting`). d_bnd: the paper's D_bnd
    (kojima; kojima_k blends every camera whose cosine is within D_bnd of the primary's); None
    derives it from the rig: blending over half the angle between neighbouring cameras as seen from
    the rendered surface (:func:`suggest_d_bnd`). k: cameras blended by ulr. planes: depth planes,
    uniform in inverse depth between near and far (metres along the virtual axis; None: the rig's
    ``depth_range``, else the range of the rig's working volume from its geometry alone,
    :meth:`workers.sweep.rig.Rig.auto_depth_range`).
    visual_hull: cull with the silhouettes (None: when the renderer has silhouettes).
    coarse_to_fine: sweep all planes at half resolution (choosing by ``aggregation``), then only a window
    of ``refine_margin`` planes around the coarse choice at full resolution (winner-take-all there). consistency: variance of the camera samples, or its
    truncated form (each camera's squared deviation capped at ``truncation``^2).
    min_views: cameras that must see a point for it to be tested. subpixel_bits: 1..6 rounds the depth
    search's sampling positions to 1/2**bits px (5 matches OpenCV's warps, for like-for-like checks
    against :mod:`workers.sweep.reference`); 0 and values above 6 use the search's finest step, 1/64 px
    (the colour is always sampled at the exact position). fill: BGR colour where no depth.

    aggregation: how a pixel's plane is chosen (:mod:`workers.sweep.costs`). "none": alone, on its own
    cameras' variance (winner-take-all, the exactly pruned fast search); "window": on the variance over a
    (2 ``window`` + 1)^2 px window; "sgm": the windowed cost, as an RMS deviation capped at ``cost_cap``
    colour levels, then semi-global aggregation along ``sgm_directions`` scanlines with penalties
    ``sgm_p1`` (one plane) and ``sgm_p2`` (a larger jump), in colour levels. Both aggregations build the
    whole cost volume of the search window (no pruning) and place the depth between planes by a parabola
    through the aggregated costs (``subplane``). The truncated consistency needs aggregation "none" (its
    default then).

    visibility: colour each pixel only from the cameras that its surface point is not hidden from by a
    nearer surface of the rendered view (z-buffers of the view's own depth map splatted into every camera,
    :mod:`workers.sweep.visibility`); a hidden camera is treated as one whose image does not contain the
    point, and where every camera is hidden all take part. True: at every pixel; False: nowhere; None (the
    default): at the pixels the occlusion fill gave a depth (``occlusions`` "fill"; nowhere with "keep"): the
    half-occluded strips, whose background one camera does not see, which it then colours from the cameras
    that do. Elsewhere the fill's cross-view check has confirmed the pixel's depth in at least ``min_views``
    cameras' own choices, and the test can only lose: with the sweep's depth, wrong by a plane or two here and
    there, neighbouring pixels of one surface hide each other from the cameras (benchmarks/RESULTS.md, section
    sweep, "The viewer's quality levels": on every pixel it cost up to 2 dB on Middlebury Teddy from eight views and
    dropped the camera a view stands on at 6% of the demo studio's pixels after the fill, 18% without it: 52 ->
    32 dB, and 27 dB). visibility_tolerance: relative depth
    margin of that test (0.2: a point counts as hidden when something is more than 20% nearer along the camera's
    axis); the sweep's depth steps are 2-3% per plane at 48-64 planes, and its errors span several planes on slanted
    and weakly textured surfaces, so a margin of one plane (0.03, the default before) hides a surface from itself;
    of 0.03, 0.06, 0.1 and 0.2, 0.2 scored best or level on every Middlebury set and studio view tried.

    occlusions: "keep" the searched depth everywhere, or "fill" the pixels whose plane the cameras do not
    confirm (half-occluded strips next to depth edges and at the frame's edge, mismatches) with the farther
    of the neighbouring confirmed depths along the rows (the columns for a vertically spread rig), as
    classic stereo does after its left-right check (:mod:`workers.sweep.occlusion`). The check runs on the
    aggregated cost volume, so "fill" needs aggregation "window" or "sgm"; with coarse_to_fine the fine level
    then aggregates too (within its narrow plane windows) instead of the pruned search. Against keep (section
    sweep of benchmarks/RESULTS.md, "The viewer's quality levels") it gains on Middlebury Teddy and Art from two
    views and from all and on the demo studio, and in the band around occluding edges, but loses on the wide
    ring of templeSparseRing (its check rejects mismatches there, which the background's depth does not mend);
    it costs a scan of the cost volume per camera, so the library's default is "keep" (the viewer's "best"
    quality level fills: workers/streaming/quality.py).
    """

    model_config = ConfigDict(extra="forbid")

    method: Literal["kojima", "kojima_k", "nearest", "ulr", "global"] = "kojima"
    d_bnd: float | None = Field(None, gt=0.0, le=2.0,
                                description="the paper's D_bnd; None: derived from the rig (suggest_d_bnd)")
    k: int = Field(3, ge=2, le=8)
    planes: int = Field(48, ge=2, le=MAX_PLANES)
    near: float | None = Field(None, gt=0.0)
    far: float | None = Field(None, gt=0.0)
    visual_hull: bool | None = None
    coarse_to_fine: bool = False
    refine_margin: int = Field(2, ge=0, le=64)
    consistency: Literal["variance", "truncated"] = "variance"
    truncation: float = Field(30.0, gt=0.0)
    min_views: int = Field(2, ge=1)
    subpixel_bits: int = Field(0, ge=0, le=10)
    fill: tuple[int, int, int] = (0, 0, 0)
    aggregation: Literal["none", "window", "sgm"] = Field(
        "window", description="how each pixel's depth plane is chosen: 'none' alone (winner-take-all, fastest), "
                              "'window' on the cameras' variance over a 5x5 px window, 'sgm' the windowed cost "
                              "with semi-global smoothing (best on real scenes, slowest); see "
                              "workers.sweep.costs")
    window: int = Field(2, ge=0, le=15)
    cost_cap: float = Field(40.0, gt=0.0, le=1000.0)
    sgm_p1: float = Field(2.0, ge=0.0, le=1000.0)
    sgm_p2: float = Field(32.0, ge=0.0, le=1000.0)
    sgm_directions: Literal[4, 8] = 8
    subplane: bool = True
    visibility: bool | None = Field(
        None, description="colour each pixel only from the cameras its surface point is not hidden from by a "
                          "nearer surface of the view (per-camera z-buffers of the rendered depth); see "
                          "workers.sweep.visibility. True: every pixel; None: the pixels the occlusion fill "
                          "gave a depth (none when occlusions is 'keep')")
    visibility_tolerance: float = Field(0.2, ge=1e-4, le=1.0)
    occlusions: Literal["keep", "fill"] = Field(
        "keep", description="'fill': the pixels whose depth plane the cameras do not confirm (half-occluded strips "
                            "next to depth edges, mismatches) take the farther neighbouring depth along the "
                            "scanline, as classic stereo does after its left-right check; 'keep': the searched "
                            "depth everywhere; see workers.sweep.occlusion")

    @model_validator(mode="after")
    def _compatible(self) -> "RenderOptions":
        if self.aggregation != "none" and self.consistency != "variance":
            if "aggregation" not in self.model_fields_set:  # the default follows the cost asked for
                self.aggregation = "none"
                return self
            raise ValueError(f"aggregation {self.aggregation!r} works on the variance cost; use aggregation 'none' "
                             f"with the {self.consistency} cost")
        if self.occlusions == "fill" and self.aggregation == "none":
            raise ValueError("occlusions 'fill' checks the planes on a cost volume: use aggregation 'window' or 'sgm' "
                             "(the pruned search of aggregation 'none' keeps none)")
        if self.sgm_p1 > self.sgm_p2:
            raise ValueError(f"sgm_p1 ({self.sgm_p1}) must not exceed sgm_p2 ({self.sgm_p2})")
        return self

    @property
    def visibility_scope(self) -> Literal["all", "filled", "none"]:
        """Where the colour is visibility-aware: every pixel (``visibility`` True), the occlusion fill's pixels
        (``visibility`` None with ``occlusions`` "fill"), or nowhere."""
        if self.visibility is not None:
            return "all" if self.visibility else "none"
        return "filled" if self.occlusions == "fill" else "none"


@dataclass(frozen=True)
class RenderResult:
    """One rendered virtual view.

    image (h, w, 3) uint8 BGR; depth (h, w) float32 metres along the virtual axis, inf where no
    surface was found; regions (h, w) uint8: cameras with non-zero weight (kojima: 1 one-camera
    region, 2 two-camera region; kojima_k also 3 and more; 0 no surface); primary (h, w) int16: index of the nearest-angle
    camera (-1 none), which shows the one-camera regions of Fig. 4(a); cost (h, w) float32: the
    photo-consistency at the chosen plane (the variance without aggregation, else the aggregated cost);
    planes (P,) float64 plane depths; plane_index (h, w) int32 the chosen plane (-1 none); plane_offset
    (h, w) float32 the sub-plane position in planes (-0.5..0.5; the depth is at inverse depth
    s[plane_index] + plane_offset * (s[1] - s[0])); filled (h, w) bool: the pixels whose depth the occlusion
    fill replaced (their cost is NaN; all False unless occlusions is "fill"); occlusions: the option the depth
    was made with ("keep" or "fill"; re-shading with visibility None follows it); visual_hull: whether the hull
    culled; d_bnd: the D_bnd used (kojima, kojima_k; None for the other methods); timings: ms per stage;
    frame_set: the renderer's stamp of the frame set it was made from (:class:`workers.sweep.temporal.ChangeTracker`);
    held (h, w) bool: the pixels whose depth a ``previous`` render gave, the scene there not having moved since
    (all False without one).
    """

    camera: Camera
    image: np.ndarray
    depth: np.ndarray
    regions: np.ndarray
    primary: np.ndarray
    cost: np.ndarray
    planes: np.ndarray
    plane_index: np.ndarray
    plane_offset: np.ndarray
    filled: np.ndarray
    occlusions: str
    visual_hull: bool
    d_bnd: float | None
    timings: dict[str, float] = field(default_factory=dict)
    frame_set: tuple[int, int] = (0, 0)
    held: np.ndarray | None = None


class SweepRenderer:
    """Plane-sweep renderer for one rig; holds the current frame set and its silhouettes.

    rig: a :class:`Rig` (or a sequence of cameras). images: one (H, W, 3) uint8 BGR per camera, sized
    as its calibration. silhouettes: one (H, W) bool per camera, or backgrounds: one empty-scene image
    per camera (silhouettes then come from background subtraction with ``bg_threshold``); with
    neither, there is no visual hull. hull_dilate: pixels added around each silhouette so that small
    silhouette or calibration errors do not carve the object. Distorted cameras are undistorted once
    here (same K).

    device: where the depth search runs: "cpu", "cuda" (an NVIDIA GPU through numba's CUDA target,
    :mod:`workers.sweep.gpu`; an error when there is none) or "auto" (the GPU when one is present);
    None: the worker setting ``sweep_device`` (``SWEEPCAST_SWEEP_DEVICE``, default "auto"). The colour pass runs on the CPU either way.
    A GPU that fails at its first use (a driver without the CUDA compiler, say) is logged and left for
    the CPU. ``self.device`` says which one runs.
    """

    def __init__(
        self, rig: Rig | Sequence[Camera], images: Sequence[np.ndarray], *,
        silhouettes: Sequence[np.ndarray] | None = None, backgrounds: Sequence[np.ndarray] | None = None,
        bg_threshold: float = BG_THRESHOLD, hull_dilate: int = HULL_DILATE_PX,
        device: Literal["auto", "cpu", "cuda"] | None = None,
    ) -> None:
        self.rig = rig if isinstance(rig, Rig) else Rig(tuple(rig))
        self.cameras = [Camera(c.name, c.K, c.R, c.t, c.width, c.height) for c in self.rig.cameras]
        self._undistort = [undistort_maps(c) for c in self.rig.cameras]
        self.bg_threshold = float(bg_threshold)
        self.hull_dilate = int(hull_dilate)
        self.backgrounds = None
        if backgrounds is not None:
            self.backgrounds = [self.undistort(i, b) for i, b in enumerate(self._checked(backgrounds, "background"))]
        n = len(self.cameras)
        hm = max(c.height for c in self.cameras)
        wm = max(c.width for c in self.cameras)
        self._imgs = np.zeros((n, hm, wm, 3), np.uint8)  # for the colour
        self._pix = np.zeros((n, hm + 1, wm + 1), np.uint64)  # for the depth search (kernels.pack_images)
        self._sils = np.ones((n, hm, wm), np.uint8)
        self._zbuffers = ZBufferStore((n, hm, wm))  # visibility: the view's surface per camera (float32 m)
        self._changes = ChangeTracker((n, hm, wm))  # temporal consistency: which camera pixels moved when
        self._sil_bounds = np.empty((n, 6))  # per camera: W-1, H-1, silhouette box (kernels.hull_windows)
        self._sizes = np.array([[c.width, c.height] for c in self.cameras], np.int64)
        self._P = np.stack([c.P for c in self.cameras])
        self._centers = np.stack([c.center for c in self.cameras])
        self._focals = np.array([max(c.K[0, 0], c.K[1, 1]) for c in self.cameras])
        self._axes = np.stack([c.axis for c in self.cameras])
        self.has_silhouettes = False
        self._gpu = None
        self.set_frames(images, silhouettes)
        self.device = "cpu"
        device = device or worker_settings().sweep_device
        if wants_gpu(device):
            from .gpu import GpuSweep
            try:
                self._gpu = GpuSweep(self._imgs, self._sils, self._sizes)
                self.device = "cuda"
            except Exception:  # noqa: BLE001 - "auto" never fails for want of a working GPU
                if device == "cuda":
                    raise
                log.exception("the GPU could not take the frames; this renderer uses the CPU")

    # --- frames -------------------------------------------------------------------------------
    def set_frames(self, images: Sequence[np.ndarray], silhouettes: Sequence[np.ndarray] | None = None) -> None:
        """Replace the current frame set (one synchronised image per camera, uint8 BGR); silhouettes
        as in the constructor (background subtraction when the renderer has backgrounds)."""
        imgs = self._checked(images, "image")
        sils = None
        if silhouettes is not None:
            sils = [self.undistort(i, np.asarray(s, bool).astype(np.uint8), nearest=True).astype(bool)
                    for i, s in enumerate(self._checked(silhouettes, "silhouette", channels=None))]
        for i, img in enumerate(imgs):
            img = self.undistort(i, img)
            c = self.cameras[i]
            self._imgs[i, :c.height, :c.width] = img
            if sils is None and self.backgrounds is not None:
                sil = silhouette_from_background(img, self.backgrounds[i], self.bg_threshold)
            else:
                sil = sils[i] if sils is not None else None
            if sil is not None:
                self._sils[i, :c.height, :c.width] = dilate(sil, self.hull_dilate)
        kernels.pack_images(self._imgs, self._sizes, self._pix)
        self._changes.update(self._imgs, self._sizes)
        for i, c in enumerate(self.cameras):
            self._sil_bounds[i] = (c.width - 1, c.height - 1) + silhouette_box(self._sils[i, :c.height, :c.width])
        self.has_silhouettes = sils is not None or self.backgrounds is not None
        if self._gpu is not None:
            self._gpu.set_frames(self._imgs, self._sils)

    def silhouettes(self) -> list[np.ndarray]:
        """The (dilated) silhouettes in use, (H, W) bool per camera (all True without a hull)."""
        return [self._sils[i, :c.height, :c.width].astype(bool) for i, c in enumerate(self.cameras)]

    # --- rendering ----------------------------------------------------------------------------
    def render(self, virtual: Camera, options: RenderOptions | None = None, previous: RenderResult | None = None,
               **kwargs: object) -> RenderResult:
        """Render the view of ``virtual`` (any size; its distortion is ignored).

        Options come as a :class:`RenderOptions` or as its fields in keyword arguments
        (``method=``, ``d_bnd=``, ``k=``, ``planes=``, ``near=``, ``far=``, ...).

        previous: this renderer's render of the same view (camera, planes and depth options) from an earlier frame
        set, for a picture that does not flicker where the scene stands still: its depth (and fill) is kept at
        every pixel whose point the cameras see at pixels unchanged since its set (:mod:`workers.sweep.temporal`;
        ``held`` says where), and its derived D_bnd too. Ignored when it is another view's or another renderer's.
        """
        t0 = time.perf_counter()
        if options is None:
            opt = RenderOptions(**kwargs)
        else:
            opt = RenderOptions(**{**options.model_dump(), **kwargs}) if kwargs else options
        if virtual.width * virtual.height > MAX_VIEW_PIXELS:
            raise RigError(virtual.name, "size", f"{virtual.width}x{virtual.height} is larger than allowed")
        near, far = self._depth_range(virtual, opt)
        s_planes = np.linspace(1.0 / near, 1.0 / far, opt.planes)
        use_hull = self.has_silhouettes if opt.visual_hull is None else bool(opt.visual_hull)
        if use_hull and not self.has_silhouettes:
            raise RigError(None, "visual_hull", "requested, but the renderer has no silhouettes or backgrounds")
        timings: dict[str, float] = {}
        t1 = time.perf_counter()
        timings["prepare_ms"] = (t1 - t0) * 1e3
        h, w = virtual.height, virtual.width
        Q, B, G = self.geometry(virtual)
        coarse = opt.coarse_to_fine and min(h, w) >= 8
        if coarse:
            coarse_cam = virtual.scaled(0.5)
            Qc, Bc, _ = self.geometry(coarse_cam)
            window = self.search_window(Qc, Bc, coarse_cam.height, coarse_cam.width, s_planes, use_hull)
            best_c, _, _, _ = self._choose(Qc, Bc, virtual.center, s_planes, use_hull, opt, *window)
            lo = np.empty((h, w), np.int32)
            hi = np.empty((h, w), np.int32)
            kernels.refine_windows(best_c, h, w, REFINE_RADIUS, opt.refine_margin, opt.planes, lo, hi)
            t2 = time.perf_counter()
            timings["coarse_ms"] = (t2 - t1) * 1e3
            t1 = t2
        else:
            lo, hi = self.search_window(Q, B, h, w, s_planes, use_hull)
        # after an aggregated coarse level the fine search stays within a few planes of its choice: there
        # the pruned winner-take-all search keeps the full resolution's detail at a fraction of the cost; the
        # occlusion fill's check needs the cost volume, so with it the fine level aggregates within those windows
        fine = opt.model_copy(update={"aggregation": "none"}) if coarse and opt.occlusions == "keep" else opt
        best, cost, offset, volume = self._choose(Q, B, virtual.center, s_planes, use_hull, fine, lo, hi)
        t2 = time.perf_counter()
        timings["sweep_ms"] = (t2 - t1) * 1e3
        filled = np.zeros(best.shape, bool)
        if opt.occlusions == "fill":
            best, offset, filled = self._fill_occlusions(virtual, Q, B, s_planes, best, offset, volume, lo, hi, opt)
            cost = np.where(filled, np.float32(np.nan), cost)
            t1, t2 = t2, time.perf_counter()
            timings["occlusions_ms"] = (t2 - t1) * 1e3
        held = self._still_since(previous, virtual, Q, B, G, s_planes, opt)
        if held is not None:
            best, offset, cost, filled = (np.where(held, kept, new) for kept, new in (
                (previous.plane_index, best), (previous.plane_offset, offset), (previous.cost, cost),
                (previous.filled, filled)))
            t1, t2 = t2, time.perf_counter()
            timings["held_ms"] = (t2 - t1) * 1e3
        s_pix = pixel_inverse_depth(s_planes, best, offset)
        with np.errstate(divide="ignore"):
            depth = (1.0 / s_pix).astype(np.float32)  # inf where s_pix is 0 (no surface)
        d_bnd = self._d_bnd(virtual, depth, opt)
        if held is not None and opt.d_bnd is None and previous.d_bnd is not None and d_bnd is not None:
            d_bnd = previous.d_bnd  # derived from the same viewpoint: a new median depth would recolour still parts
        image, regions, primary = self.shade(virtual, Q, B, G, s_pix, use_hull, opt, d_bnd, filled)
        t3 = time.perf_counter()
        timings["shade_ms"] = (t3 - t2) * 1e3
        timings["total_ms"] = (t3 - t0) * 1e3
        return RenderResult(virtual, image, depth, regions, primary, cost, 1.0 / s_planes, best, offset, filled,
                            opt.occlusions, use_hull, d_bnd, timings, self._changes.stamp,
                            held if held is not None else np.zeros(best.shape, bool))

    def reshade(self, previous: RenderResult, options: RenderOptions | None = None, **kwargs: object) -> RenderResult:
        """The view of ``previous`` (same camera, same depth) coloured with other weighting options
        (``method``, ``d_bnd``, ``k``, ``fill``, ``visibility``): no new sweep. The frames must be the same."""
        t0 = time.perf_counter()
        opt = _for_previous(previous, options, kwargs)
        virtual = previous.camera
        Q, B, G = self.geometry(virtual)
        s_planes = 1.0 / previous.planes
        d_bnd = self._d_bnd(virtual, previous.depth, opt)
        s_pix = pixel_inverse_depth(s_planes, previous.plane_index, previous.plane_offset)
        image, regions, primary = self.shade(virtual, Q, B, G, s_pix, previous.visual_hull, opt, d_bnd,
                                             previous.filled)
        ms = (time.perf_counter() - t0) * 1e3
        return replace(previous, image=image, regions=regions, primary=primary, d_bnd=d_bnd,
                       timings={"shade_ms": ms, "total_ms": ms})

    def blend_weights(self, previous: RenderResult, options: RenderOptions | None = None,
                      **kwargs: object) -> np.ndarray:
        """Each camera's colour weight at each pixel of ``previous`` (same camera, same depth, same
        frames) under the weighting options (``method``, ``d_bnd``, ``k``, ``visibility``), as :meth:`reshade` would
        colour it: (h, w, N) float32, N the rig's cameras in rig order; a pixel's weights sum to 1
        (all 0 where there is no surface). For diagnostics: where the blended set of cameras changes,
        how far a weight moves from pixel to pixel."""
        opt = _for_previous(previous, options, kwargs)
        virtual = previous.camera
        Q, B, G = self.geometry(virtual)
        d_bnd = self._d_bnd(virtual, previous.depth, opt)
        s_pix = pixel_inverse_depth(1.0 / previous.planes, previous.plane_index, previous.plane_offset)
        weights = np.empty(s_pix.shape + (len(self.cameras),), np.float32)
        self.shade(virtual, Q, B, G, s_pix, previous.visual_hull, opt, d_bnd, previous.filled, weights=weights)
        return weights

    def auto_d_bnd(self, virtual: Camera, depth: np.ndarray) -> float:
        """D_bnd blending over half the angle between neighbouring cameras, seen from the surface
        point on ``virtual``'s central ray at the median of ``depth`` (h, w) (1 m without any). Cameras
        that all share one centre have no spacing: then the D_bnd of cameras FALLBACK_SPACING_RAD apart."""
        ok = np.isfinite(depth) & (depth > 0)
        z = float(np.median(depth[ok])) if ok.any() else 1.0
        centre = np.array([[(virtual.width - 1) / 2, (virtual.height - 1) / 2]])
        spacing = neighbour_angle(self._centers, virtual.backproject(centre, z)[0])
        return suggest_d_bnd(spacing if spacing > 0 else FALLBACK_SPACING_RAD, AUTO_BLEND_FRACTION)

    def _d_bnd(self, virtual: Camera, depth: np.ndarray, opt: RenderOptions) -> float | None:
        if opt.method not in ("kojima", "kojima_k"):
            return None
        return opt.d_bnd if opt.d_bnd is not None else self.auto_d_bnd(virtual, depth)

    def depth_planes(self, virtual: Camera, planes: int, near: float | None = None, far: float | None = None) -> np.ndarray:
        """The plane depths (P,) float64 a render with these options would test, nearest first."""
        n, f = self._depth_range(virtual, RenderOptions(planes=planes, near=near, far=far))
        return 1.0 / np.linspace(1.0 / n, 1.0 / f, planes)

    # --- internals ----------------------------------------------------------------------------
    def _depth_range(self, virtual: Camera, opt: RenderOptions) -> tuple[float, float]:
        if opt.near is None or opt.far is None:
            auto_near, auto_far = self.rig.auto_depth_range(virtual)
        near = opt.near if opt.near is not None else auto_near
        far = opt.far if opt.far is not None else auto_far
        if not near < far:
            raise RigError(virtual.name, "near/far", f"needs near < far, got {near:g} and {far:g}")
        return near, far

    def geometry(self, virtual: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The maps from ``virtual``'s pixels to the cameras', float64: Q (N, 3, 3) and B (N, 3) (camera i sees the
        virtual pixel (u, v) at inverse depth s, 1/m along the virtual axis, at Q[i] (u, v, 1) + s B[i],
        homogeneous), and G (3, 3) (the virtual pixel's ray); see :mod:`workers.sweep.kernels`. What
        :meth:`search_window`, :meth:`sweep` and :meth:`shade` take."""
        G = virtual.R.T @ np.linalg.inv(virtual.K)
        M = self._P[:, :, :3]
        Q = np.ascontiguousarray(M @ G)
        B = np.ascontiguousarray(M @ virtual.center + self._P[:, :, 3])
        return Q, B, G

    def shade(self, virtual: Camera, Q: np.ndarray, B: np.ndarray, G: np.ndarray, s_pix: np.ndarray,
              use_hull: bool, opt: RenderOptions, d_bnd: float | None, filled: np.ndarray | None = None,
              weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The colour pass at depths the caller gives (a render shades its own; a benchmark an oracle's): image
        (h, w, 3) uint8, regions (h, w) uint8 and primary (h, w) int16 at the inverse depths s_pix (h, w) float64
        (1/m; 0 where no surface); Q, B, G from :meth:`geometry`; d_bnd: Kojima's boundary distance (None: 1);
        ``filled`` (h, w) bool: the occlusion fill's pixels
        (the visibility test's pixels when ``opt.visibility_scope`` is "filled"); fills ``weights`` (h, w, N)
        float32 with every camera's weight when given."""
        h, w = s_pix.shape
        image = np.empty((h, w, 3), np.uint8)
        regions = np.empty((h, w), np.uint8)
        primary = np.empty((h, w), np.int16)
        gcam = global_camera(self._axes, virtual.axis)
        scope = opt.visibility_scope
        if scope == "filled" and (filled is None or not filled.any()):
            scope = "none"  # nothing filled: no pixel to test
        vis_mask = np.ascontiguousarray(filled, np.bool_) if scope == "filled" else np.empty((0, 0), np.bool_)
        with self._zbuffers.taken() if scope != "none" else nullcontext() as store:
            if store is not None:
                zbuf, zbox = surface_zbuffers(Q, B, s_pix, self._sizes, store.shape, out=store)
            else:
                zbuf, zbox = np.empty((0, 0, 0), np.float32), np.empty((0, 4), np.int64)
            kernels.shade(Q, B, s_pix, self._imgs, self._sizes, self._sils, use_hull, self._centers,
                          virtual.center, G, METHOD_CODES[opt.method], d_bnd or 1.0, opt.k, gcam,
                          np.asarray(opt.fill, np.uint8), image, regions, primary,
                          weights if weights is not None else np.empty((0, 0, 0), np.float32),
                          zbuf, zbox, opt.visibility_tolerance, vis_mask,
                          self._focals * np.linalg.norm(self._centers - virtual.center, axis=1))
        return image, regions, primary

    def _choose(self, Q: np.ndarray, B: np.ndarray, center: np.ndarray, s_planes: np.ndarray, use_hull: bool,
                opt: RenderOptions, lo: np.ndarray, hi: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """Best plane (h, w) int32 (-1 none), its cost (h, w) float32, the sub-plane offset (h, w) float32
        (planes) in windows lo..hi, by ``opt.aggregation``: the pruned winner-take-all search, or the
        aggregated cost volume (:mod:`workers.sweep.costs`); and that volume (h, w, P) float32 (None for the
        pruned search, which builds none, and on the GPU unless the occlusion fill needs it). On the GPU when the
        renderer has one."""
        if self._gpu is not None and opt.consistency == "variance":
            try:
                bits = search_bits(opt)
                return self._gpu.choose(Q, B, s_planes, use_hull, opt.min_views, bits, lo, hi, opt.aggregation,
                                        opt.window, opt.subplane, opt.cost_cap, opt.sgm_p1, opt.sgm_p2,
                                        opt.sgm_directions, want_volume=opt.occlusions == "fill")
            except Exception:  # noqa: BLE001 - e.g. a driver without NVVM: the CPU still renders
                log.exception("the GPU depth search failed; this renderer goes on with the CPU")
                self._gpu = None
                self.device = "cpu"
        if opt.aggregation == "none":
            best, cost = self.sweep(Q, B, center, s_planes, use_hull, opt, lo, hi)
            return best, cost, np.zeros(best.shape, np.float32), None
        ssd, votes = self._volume(Q, B, center, s_planes, use_hull, opt, lo, hi)
        volume = aggregate(ssd, votes, opt, (lo, hi))
        best, cost, offset = costs.winner(volume)
        if not opt.subplane:
            offset[:] = 0.0
        return best, cost, offset, volume

    def _still_since(self, previous: RenderResult | None, virtual: Camera, Q: np.ndarray, B: np.ndarray, G: np.ndarray,
                     s_planes: np.ndarray, opt: RenderOptions) -> np.ndarray | None:
        """The pixels (h, w) bool where ``previous`` (a render of ``virtual`` with the same planes and depth options,
        from an earlier frame set of this renderer) still holds (:meth:`ChangeTracker.still_pixels`), or None when it
        is not such a render."""
        if previous is None or previous.occlusions != opt.occlusions:
            return None
        cam = previous.camera
        same_view = (cam.width, cam.height) == (virtual.width, virtual.height) and all(
            np.array_equal(a, b) for a, b in ((cam.K, virtual.K), (cam.R, virtual.R), (cam.t, virtual.t)))
        if not same_view or not np.array_equal(previous.planes, 1.0 / s_planes):
            return None
        s_prev = pixel_inverse_depth(s_planes, previous.plane_index, previous.plane_offset)
        return self._changes.still_pixels(Q, B, G, virtual.center, self._centers, s_prev, self._sizes,
                                          previous.frame_set)

    def _fill_occlusions(self, virtual: Camera, Q: np.ndarray, B: np.ndarray, s_planes: np.ndarray, best: np.ndarray,
                         offset: np.ndarray, volume: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                         opt: RenderOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The depth (best, offset) with the pixels whose plane fewer than ``min_views`` cameras' own choices from the
        cost volume confirm (``volume`` (h, w, P) float32 with plane windows lo..hi; the cross-view check of
        :mod:`workers.sweep.occlusion`) given the farther neighbouring depth along the line, and the mask (h, w)
        bool of those pixels. (A visibility check instead, a point seen by fewer than two cameras past the view's
        own depth, was tried too: on Middlebury Teddy it lost quality after the per-pixel search and gained less
        than the cross-view check after sgm, since it also rejects the many pixels whose depth is noisy but whose
        colour is right.)"""
        bad = confirmed_views(Q, B, s_planes, volume, lo, hi, best, self._sizes) < opt.min_views
        bad &= best >= 0
        best, offset = background_fill(best, offset, s_planes, bad, fill_along_rows(virtual, self._centers))
        return best, offset, bad

    def _volume(self, Q: np.ndarray, B: np.ndarray, center: np.ndarray, s_planes: np.ndarray, use_hull: bool,
                opt: RenderOptions, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The unpruned sums ssd, votes (h, w, P) float32 of windows lo..hi (:func:`lane_cost_volume`)."""
        shape = lo.shape + (len(s_planes),)
        ssd = np.empty(shape, np.float32)
        votes = np.empty(shape, np.float32)
        bits = search_bits(opt)
        camf, cami = self._camera_table(Q, B, center, bits)
        lane_cost_volume(camf, cami, self._pix.reshape(-1), self._sils.reshape(-1), use_hull, opt.min_views, bits,
                         s_planes, lo, hi, self._bands(lo.shape[0]), BAND_ROWS, ssd, votes)
        return ssd, votes

    def sweep(self, Q: np.ndarray, B: np.ndarray, center: np.ndarray, s_planes: np.ndarray, use_hull: bool,
              opt: RenderOptions, lo: np.ndarray, hi: np.ndarray, lanes: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """The depth search alone: best plane (h, w) int32 and its cost (h, w) float32 among the planes s_planes
        (P,) (inverse depths, 1/m) within the windows lo..hi (:meth:`search_window`); center (3,): the
        virtual camera's centre; lanes False: the variance cost's per-pixel search (the same result; the
        baseline the 16-lane search is measured against)."""
        best = np.empty(lo.shape, np.int32)
        cost = np.empty(lo.shape, np.float32)
        trunc2 = opt.truncation**2 if opt.consistency == "truncated" else 0.0
        bits = search_bits(opt)
        camf, cami = self._camera_table(Q, B, center, bits)
        kernels.sweep_depth(camf, cami, self._pix.reshape(-1), self._sils.reshape(-1), use_hull, opt.min_views,
                            trunc2, bits, s_planes, lo, hi, self._bands(lo.shape[0]), BAND_ROWS, best, cost, lanes)
        return best, cost

    def _camera_table(self, Q: np.ndarray, B: np.ndarray, center: np.ndarray, bits: int) -> tuple[np.ndarray, np.ndarray]:
        """The sweep kernel's per-camera rows, (N * CAM_F,) float64 and (N * CAM_I,) int64 (see
        :mod:`workers.sweep.kernels`), in sampling order: nearest to the virtual centre (3,) first. A
        near camera sees every plane of a pixel at nearly the same place, so its samples come from
        cache (a little less time than widely spread cameras first or the rig's order)."""
        n, hm, wm = self._sils.shape
        camf = np.zeros((n, kernels.CAM_F))
        cami = np.zeros((n, kernels.CAM_I), np.int64)
        order = np.argsort(np.linalg.norm(self._centers - center, axis=1), kind="stable")
        for row, i in enumerate(order):
            w, h = self._sizes[i]
            camf[row, :9] = Q[i].ravel()
            camf[row, 9:12] = B[i]
            cami[row, :6] = ((w - 1) << bits, (h - 1) << bits, i * (hm + 1) * (wm + 1), wm + 1, i * hm * wm, wm)
        return camf.reshape(-1), cami.reshape(-1)

    @staticmethod
    def _bands(h: int) -> np.ndarray:
        """Row bands (nb,) int64 in the order the kernel's threads take them: numba gives each thread one
        contiguous share of the list, so interleaving hands every thread bands from the whole view
        (the object, where the work is, usually sits in the middle)."""
        nb = -(-h // BAND_ROWS)
        threads = numba.get_num_threads()
        return np.concatenate([np.arange(t, nb, threads) for t in range(threads)]).astype(np.int64)

    def search_window(self, Q: np.ndarray, B: np.ndarray, h: int, w: int, s_planes: np.ndarray,
                      use_hull: bool) -> tuple[np.ndarray, np.ndarray]:
        """Plane windows lo, hi (h, w) int32 of a full search: every plane, or with the hull only those
        inside all silhouettes' bounding boxes (kernels.hull_windows)."""
        lo = np.zeros((h, w), np.int32)
        hi = np.full((h, w), len(s_planes) - 1, np.int32)
        if use_hull:
            kernels.hull_windows(Q, B, self._sil_bounds, s_planes, lo, hi)
        return lo, hi

    def _checked(self, arrays: Sequence[np.ndarray], what: str, channels: int | None = 3) -> list[np.ndarray]:
        arrays = list(arrays)
        if len(arrays) != len(self.rig.cameras):
            raise RigError(None, what, f"{len(arrays)} given for {len(self.rig.cameras)} cameras")
        out = []
        for cam, a in zip(self.rig.cameras, arrays):
            a = np.asarray(a)
            want = (cam.height, cam.width) + ((channels,) if channels else ())
            if a.shape != want:
                raise RigError(cam.name, f"{what} size", f"got shape {a.shape}, calibration says {want}")
            if channels and a.dtype != np.uint8:
                raise RigError(cam.name, what, f"must be uint8, got {a.dtype}")
            out.append(a)
        return out

    def undistort(self, i: int, img: np.ndarray, nearest: bool = False) -> np.ndarray:
        """``img`` (H, W[, C]) of camera ``i`` (rig order) as the renderer holds its frames: undistorted (the same
        array when the camera has no distortion); ``nearest``: nearest-neighbour remap (masks)."""
        return undistorted(self._undistort[i], img, nearest)

    def camera_image(self, i: int) -> np.ndarray:
        """Camera ``i``'s current frame as the search and the colour pass sample it: (H, W, 3) uint8 BGR,
        undistorted (a view of the renderer's own buffer: read it, do not write it)."""
        c = self.cameras[i]
        return self._imgs[i, :c.height, :c.width]


def search_bits(opt: RenderOptions) -> int:
    """The depth search's sampling step, 1/2**bits px, for ``opt.subpixel_bits`` (0 or above MAX_BITS: the finest)."""
    return opt.subpixel_bits if 0 < opt.subpixel_bits <= kernels.MAX_BITS else kernels.MAX_BITS


def wants_gpu(device: str) -> bool:
    """Whether a renderer asked for ``device`` (auto, cpu or cuda; see :class:`SweepRenderer`) runs its search
    on the GPU."""
    if device == "cpu":
        return False
    if device not in ("auto", "cuda"):
        raise ValueError(f"device must be auto, cpu or cuda, got {device!r}")
    # no driver device node: no GPU, and no import of numba's CUDA target (half a second of start-up)
    if device == "auto" and not any(os.path.exists(p) for p in ("/dev/nvidiactl", "/dev/nvidia0")):
        return False
    from . import gpu
    if device == "auto":
        return gpu.available()
    if not gpu.cuda.is_available():
        raise ValueError("device 'cuda' asked for, but numba finds no CUDA GPU")
    return True


FALLBACK_SPACING_RAD = float(np.radians(10.0))
"""Camera spacing assumed by :meth:`SweepRenderer.auto_d_bnd` when every camera stands at one place."""
AUTO_BLEND_FRACTION = 0.5
"""The share of the way between neighbouring cameras that the automatic D_bnd blends over (:func:`suggest_d_bnd`)."""


def _for_previous(previous: RenderResult, options: RenderOptions | None, kwargs: dict) -> RenderOptions:
    """The options of a re-shading of ``previous``: ``options`` updated by ``kwargs``; a visibility left None
    follows the occlusion option the depth was made with (its filled pixels), as the render's did."""
    opt = RenderOptions(**kwargs) if options is None else RenderOptions(**{**options.model_dump(), **kwargs})
    if opt.visibility is None:
        opt = opt.model_copy(update={"occlusions": previous.occlusions})
    return opt


def aggregate(ssd: np.ndarray, votes: np.ndarray, opt: RenderOptions,
              windows: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The cost volume (h, w, P) float32 the plane is chosen on, by ``opt.aggregation`` ("window" or
    "sgm"), from the sweep's sums ssd, votes (h, w, P) float32 (:mod:`workers.sweep.costs`). windows: the plane
    windows lo, hi (h, w) int32 the sums were taken in (no votes outside them), which the semi-global paths then
    keep to (the same result, in a fraction of the time where they are narrow)."""
    var = costs.windowed_variance(ssd, votes, opt.window)
    if opt.aggregation == "window":
        return var
    return costs.semi_global(costs.robust_cost(var, opt.cost_cap), opt.sgm_p1, opt.sgm_p2, opt.sgm_directions,
                             windows)


def pixel_inverse_depth(s_planes: np.ndarray, best: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Inverse depth (h, w) float64 (1/m) of each pixel: plane ``best`` (h, w) int32 of s_planes (P,)
    (uniform in inverse depth) moved by ``offset`` (h, w) float32 planes; 0 where best is -1."""
    ds = (s_planes[-1] - s_planes[0]) / (len(s_planes) - 1)
    s = s_planes[np.maximum(best, 0)] + offset.astype(np.float64) * ds
    return np.where(best >= 0, s, 0.0)
