"""Sweep renderer benchmark: quality of the colour weightings, the depth against classic stereo, and speed.

    python -m benchmarks.sweep [--only weighting,stereo,speed] [--quick] [--skip-data] [--list]

One results name, ``sweep`` (benchmarks/results/sweep.json, the "sweep" section of RESULTS.md), four
sections, one module each, run in this order:

- ``weighting`` (:mod:`benchmarks.sweep.weighting`, issue 22): which colour weighting: quality, seams, pops
  and blur of every method on the procedural arc rig, Middlebury Teddy and Art, templeSparseRing and the dome
  rig (triple points), and the picture of a triple junction.
- ``stereo`` (:mod:`benchmarks.sweep.stereo`, issue 20): the sweep's depth with each aggregation against
  OpenCV SGBM + DIBR on Middlebury, and the live configuration's speed with each aggregation.
- ``speed`` (:mod:`benchmarks.sweep.speed`): the fused kernel against the per-plane reference, the live
  configuration and the per-frame extras of a stream.
- ``viewer`` (:mod:`benchmarks.sweep.viewer`, issue 58): the viewer's quality levels beside every option of the
  renderer in one run: PSNR on Middlebury (two views with SGBM + DIBR as the anchor, and all views), templeSparseRing,
  the demo studio at five azimuths and a textureless occluder, the band around occluding edges, flicker on the demo
  recording, and the live speed of each level.

``--only`` re-runs some and keeps the others of the previous results file (each section's run is named in
RESULTS.md). Shared helpers: :mod:`benchmarks.sweep.common`. Before sections, the old flags were
``--weighting-only``, ``--stereo-only`` and ``--speed-only`` (now ``--only weighting`` etc.) and
``--skip-stereo`` / ``--skip-speed`` (now ``--only`` with the others).
"""
