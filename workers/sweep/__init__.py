"""Plane-sweep virtual-view rendering with view-dependent weighting (Kojima & Fujimoto).

API (import from the submodules; arrays follow workers.camera conventions, images uint8 BGR):

- ``rig``: ``Rig(cameras, image_files=(), depth_range=None)`` (>= 2 cameras, unique names),
  ``RigError`` (an ``InputError`` naming camera and field), ``depth_range_from_box(camera, lo, hi)``.
- ``rig_io``: ``load_rig(path)`` (dispatch on format), ``load_rig_json``/``save_rig_json``,
  ``rig_from_dict``/``rig_to_dict``, ``load_colmap_text(folder)``, ``load_opencv_yaml(path)``,
  ``load_middlebury_par(path)``, ``rectified_rig(files, width, height, positions, focal, baseline)``,
  ``load_middlebury_rectified(folder)``, ``load_images(rig, folder)``.
- ``virtual``: ``from_pose``, ``look_at``, ``between(rig, a, b, s)``, ``path(rig, names, steps)``,
  ``parse_pose(spec, rig)``.
- ``renderer``: ``SweepRenderer(rig, images, silhouettes=None, backgrounds=None)`` with
  ``set_frames(images, silhouettes=None)`` and ``render(virtual, options=None, previous=None, **fields) ->
  RenderResult`` (image, depth, regions, primary, cost, planes, timings, held); ``RenderOptions`` (pydantic,
  extra=forbid). Its steps, for benchmarks and tests that take one apart: ``geometry(virtual)``,
  ``search_window``, ``sweep`` (the depth search alone), ``shade`` (the colour pass at given depths),
  ``camera_image(i)``, ``undistort(i, img)``; ``wants_gpu(device)``.
- ``costs``: cost-volume aggregation shared by plane searches: ``windowed_variance(ssd, votes, radius)``,
  ``robust_cost``, ``semi_global(cost, p1, p2, directions, windows=None)``, ``winner(cost)`` (best plane +
  parabola offset).
- ``temporal``: ``ChangeTracker`` (which camera pixels changed in which frame set) for the depth a ``previous``
  render keeps where the scene stood still.
- ``occlusion``: the occlusion fill (``RenderOptions.occlusions``): ``confirmed_views`` (cross-view check on the
  cost volume), ``background_fill`` (farther neighbouring depth along the line), ``fill_along_rows``.
- ``weighting``: ``kojima_weights``, ``kojima_k_weights`` (k-camera boundary blending), ``ulr_weights``,
  ``global_camera``, ``suggest_d_bnd``, ``METHODS``.
- ``silhouette``: ``silhouette_from_background(image, background)``.
- ``reference``: ``reference_sweep`` (cv2.warpPerspective + numpy baseline), ``plane_homographies``.
- ``overlays``: ``regions_image``, ``depth_image``.
- ``cli``: ``register(subparsers)`` adds ``render``.
"""
