"""Drone-video 3D reconstruction (Konno & Kimura: FAST + optical flow with an outlier rule,
initial values from E and DLT, bundle adjustment of eq. 5).

Modules (one concept each):
- ``frames``: decode video / ordered stills, select frames, skip blur, undistort.
- ``calibration``: intrinsics from values or calibration files, sanity checks.
- ``features``, ``matching``: FAST, SIFT; the III-A rule, forward-backward check, RANSAC on E.
- ``tracks``: tracks across frames (FAST+LK or SIFT).
- ``geometry``, ``multiview``: E, pose by SVD with cheirality, DLT, keyframes, PnP.
- ``camera_models``, ``bundle``: our Levenberg–Marquardt bundle adjuster with Schur complement.
- ``bal``: BAL problem files (benchmark).
- ``reconstruction``: the incremental pipeline -> ``SparseModel``.
- ``localise``: the frames outside the map (non-keyframes, frames selection left out) registered
  afterwards by PnP, so every decoded frame gets a pose (our addition, as COLMAP poses every image).
- ``export``, ``preview``: PLY, COLMAP text, trajectory JSON; the three-view preview PNG.
- ``evaluation``: Sim(3) alignment, ATE, rotation error.
- ``params``, ``job``, ``cli``: ``ReconstructionParams``, ``run_reconstruction``, ``sweepcast reconstruct``.
"""
