"""Dense reconstruction from calibrated, posed images: a depth map per reference frame by plane sweep,
geometric consistency across neighbours, fusion into one coloured point cloud with normals.

Pipeline (:mod:`.pipeline`: :func:`densify_views` runs it in one process on any posed images, :class:`View`
objects; a job runs the same steps as tasks, a depth map per frame and the fusion per ground tile,
:mod:`workers.drone.survey`):

1. **Neighbours** (:func:`select_neighbours`, :mod:`.neighbours`): for a reference frame, every other frame is
   scored by the sparse points both see, each weighted by the triangulation angle between the two rays (a Gaussian
   around ``best_deg`` = 5 deg: too small a baseline gives no depth resolution, too large one no matching); the
   best ``neighbours`` frames with a positive score are its neighbours.
2. **Depth map** (:func:`depth_map`, :mod:`.depth`; the fused sweep :mod:`.sweep`, its work items :mod:`.tiles`): a
   sweep of ``planes`` fronto-parallel planes of the reference, uniform in inverse depth between the depths of the
   sparse points the frame sees (widened by a margin). At each plane every neighbour is resampled into the
   reference (bilinear; the plane-induced homography in the renderer's form ``Q + s B e3^T``, :mod:`.homography`)
   and compared with the reference by ZNCC over a (2 radius + 1)^2 window (:func:`workers.sweep.costs.zncc_cost`: a
   gain or offset between frames, the exposure changes of real video, does not change it); the cost of a plane is
   the mean of the best ``k`` neighbours' ``1 - ZNCC`` (:func:`workers.sweep.costs.best_k_mean`: occluded
   neighbours are left out), the winner per pixel and a parabola through its neighbours' costs give a sub-plane
   inverse depth (:func:`workers.sweep.costs.winner`). One fused, compiled kernel does all of this per tile of the
   reference and never holds the (h, w, planes) volume unless asked to (semi-global aggregation,
   :func:`workers.sweep.costs.semi_global`, needs it). Coarse to fine (the job's default): every other plane at
   half resolution first, then at full resolution each tile sweeps only the planes near the sure coarse depths. A
   pixel keeps its depth where the winning cost is at most ``max_cost`` and its window has texture (``min_std``).
3. **Consistency** (:func:`consistency`, :mod:`.consistency`): a reference pixel's 3D point is projected into each
   neighbour's depth map; the neighbour agrees when its depth there, projected back, lands within
   ``max_reprojection_px`` of the pixel and within ``max_depth_ratio`` of the depth.
4. **Fusion** (:func:`fuse`, :mod:`.fusion`): pixels that at least ``min_views`` frames (the reference included)
   agree on become one point each: the mean of the agreeing frames' points and colours, a normal from the reference
   depth map's gradient (camera space, turned towards the camera). Pixels of neighbours that took part are marked
   used, so later references do not add the same surface again.

Conventions as everywhere (:mod:`workers.camera`): world-to-camera ``x_cam = R X + t``, OpenCV axes,
pixel (0, 0) at the centre of the top-left pixel; depth is z along the optical axis in the model's units.
The outputs' formats (the PLY, the depth PNGs and their zip) are with the other exports,
:mod:`workers.drone.export`.
"""
from .consistency import Agreement, camera_normals, consistency
from .depth import DepthMap, depth_map, inverse_depth_planes
from .fusion import DenseCloud, fuse
from .homography import plane_samples, sweep_geometry
from .neighbours import depth_range, neighbours_by_centres, select_neighbours, visible_points
from .pipeline import DenseResult, densify_views, reference_frames
from .sweep import zncc_sweep
from .views import View

__all__ = ["Agreement", "DenseCloud", "DenseResult", "DepthMap", "View", "camera_normals", "consistency",
           "densify_views", "depth_map", "depth_range", "fuse", "inverse_depth_planes", "neighbours_by_centres", "plane_samples",
           "reference_frames", "select_neighbours", "sweep_geometry", "visible_points", "zncc_sweep"]
