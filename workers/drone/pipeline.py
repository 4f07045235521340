"""A whole drone reconstruction, as the job and the CLI run it: camera -> sparse model -> world frame ->
dense cloud -> map products -> files.

1. **Camera**: given intrinsics (the fast path), else a focal length from the media's metadata
   (:mod:`workers.drone.flightmeta`) that the bundle adjustment refines with radial distortion.
2. **Sparse model**: :func:`workers.drone.reconstruction.reconstruct`.
3. **World frame**: GPS positions of the frames -> robust similarity into the local UTM zone
   (:mod:`workers.drone.georef`; optionally a bundle adjustment with the GPS as a prior); without GPS the
   reconstruction's own frame, levelled when map products are asked for.
4. **Dense cloud**: :mod:`workers.drone.dense`, when asked for or needed by the map products.
5. **Map products**: DSM and orthophoto (:mod:`workers.drone.mapping`), written by
   :mod:`workers.drone.mapfiles` with the LAZ cloud.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from workers.common.jobctx import JobInputError

from .calibration import Intrinsics, from_values, parse_calibration
from .dense import DenseResult, densify, reference_frames
from .export import colmap_text, depth_zip, ply_bytes, trajectory_json
from .flightmeta import FlightMeta, centre_of, check_prior, read_flight_meta
from .frames import load_frames
from .georef import (Georeference, GeoreferenceError, apply, frame_positions_from_exif,
                     frame_positions_from_telemetry, georeference, gps_adjust, level_frame)
from .params import ReconstructionParams, max_dense_volume_from_env
from .preview import preview_png
from .reconstruction import ProgressFn, SparseModel, reconstruct
from .selfcal import FocalPrior, given_focal_prior

RESULT_NAMES = ("points.ply", "cameras.txt", "images.txt", "points3D.txt", "trajectory.json", "report.json",
                "preview.png")
DENSE_RESULT_NAMES = ("dense.ply", "depth.zip")
ORTHO_RESULT_NAMES = ("orthophoto.tif", "orthophoto.png")
DSM_RESULT_NAMES = ("dsm.tif", "dsm.png")
LAZ_NAME = "points.laz"

# Progress: the share of the whole job each part ends at (with a dense pass; without one the sparse
# model takes it all).
_SPARSE_END = 0.4
_DENSE_END = 0.85
_MAP_END = 0.96


def resolve_intrinsics(params: ReconstructionParams, calibration_file: bytes | None = None) -> Intrinsics:
    """Intrinsics from fx/fy/cx/cy, the ``calibration`` text, or an uploaded calibration file
    (in that order); ``params.distortion`` overrides the file's. Raises JobInputError when none."""
    if params.fx is not None:
        intr = from_values(params.fx, params.fy, params.cx, params.cy)
    elif params.calibration is not None:
        intr = parse_calibration(params.calibration)
    elif calibration_file is not None:
        intr = parse_calibration(calibration_file)
    else:
        raise JobInputError("missing intrinsics: give fx, fy, cx, cy (pixels) or a calibration file")
    if params.distortion is not None:
        intr = from_values(intr.fx, intr.fy, intr.cx, intr.cy, params.distortion)
    return intr


def intrinsics_given(params: ReconstructionParams, calibration_file: bytes | None) -> bool:
    """Whether the user gave intrinsics (values, calibration text or file)."""
    return params.fx is not None or params.calibration is not None or calibration_file is not None


def resolve_camera(params: ReconstructionParams, calibration_file: bytes | None, meta: FlightMeta
                   ) -> tuple[Intrinsics, FocalPrior | None, str]:
    """The intrinsics to start from, the focal prior when the lens is self-calibrated (None: used as
    they are), and where they came from. Raises JobInputError for unusable values."""
    if intrinsics_given(params, calibration_file):
        intr = resolve_intrinsics(params, calibration_file)
        if params.refine_intrinsics:
            if intr.dist is not None:
                raise JobInputError("refine_intrinsics refines its own radial distortion: give intrinsics "
                                    "without distortion coefficients")
            return intr, given_focal_prior(intr.fx), "given"
        return intr, None, "given"
    if meta.size is None:
        raise JobInputError("the media's image size cannot be read, so no focal length can be guessed: give the "
                            "intrinsics (fx, fy, cx, cy)")
    prior = meta.focal_prior()
    check_prior(prior, meta.size)
    cx, cy = centre_of(meta.size)
    intr = from_values(prior.focal_px, prior.focal_px, cx, cy)
    return intr, (None if params.refine_intrinsics is False else prior), prior.source


def dense_pass(model: SparseModel, media, params: ReconstructionParams, progress: ProgressFn | None = None,
               media_name: str | None = None) -> DenseResult:
    """Decode the reference frames of ``media`` again (undistorted with the model's intrinsics, as
    calibrated) and run :func:`workers.drone.dense.densify` on them (progress 0..1 as it reports).
    Raises JobInputError when the
    sparse model has fewer than two registered frames or an 'sgm' dense pass would hold more than
    ``$SWEEPCAST_MAX_DENSE_VOLUME`` cost-volume cells."""
    p = params
    if p.dense_aggregation == "sgm":
        cells = int(round(model.width * p.dense_scale)) * int(round(model.height * p.dense_scale)) * p.dense_planes
        limit = max_dense_volume_from_env()
        if cells > limit:
            raise JobInputError(f"dense_aggregation 'sgm' would hold {cells:,} cost-volume cells (depth-map pixels x "
                                f"planes); the limit is {limit:,}: lower dense_scale or dense_planes, or use 'window'")
    refs = reference_frames(model.registered, p.dense_frames)
    if len(refs) < 2:
        raise JobInputError(f"a dense reconstruction needs two registered frames; {len(refs)} registered")
    if progress is not None:
        progress(0.0, "dense frames")
    native = model.intrinsics.scaled(1.0 / model.scale)
    frames = load_frames(media, native, model.frame_index[refs], p.max_width, media_name)
    images = {int(f): frames[int(model.frame_index[f])] for f in refs if int(model.frame_index[f]) in frames}
    try:
        return densify(model, images, p, progress)
    except ValueError as exc:
        raise JobInputError(f"dense reconstruction: {exc}") from None


@dataclass
class Outcome:
    """Everything one run produced (see :func:`run_pipeline`)."""

    model: SparseModel
    meta: FlightMeta
    georef: Georeference | None = None
    dense: DenseResult | None = None
    level: Georeference | None = None
    """The arbitrary level frame map products use when there is no GPS."""
    products: Any = None
    ortho: bool = False
    dsm: bool = False
    timings: dict[str, float] = field(default_factory=dict)

    def result_names(self) -> list[str]:
        """The files :func:`write_outputs` writes for this outcome."""
        names = list(RESULT_NAMES)
        if self.dense is not None:
            names += DENSE_RESULT_NAMES
        if self.georef is not None:
            names.append(LAZ_NAME)
        if self.products is not None:
            names += list(ORTHO_RESULT_NAMES if self.ortho else ()) + list(DSM_RESULT_NAMES if self.dsm else ())
        return names


def run_pipeline(media: str | Path, params: ReconstructionParams, calibration: bytes | None = None,
                 telemetry: bytes | None = None, progress: ProgressFn | None = None,
                 media_name: str | None = None) -> Outcome:
    """Run every stage (module docstring) on ``media`` (a video, zip or folder of stills) with an optional
    calibration file's and telemetry (.SRT) file's bytes. ``progress(fraction, stage)`` goes from 0 to
    0.96. User-caused failures raise JobInputError."""
    report = (lambda f, s: progress(f, s)) if progress is not None else (lambda f, s: None)
    meta = read_flight_meta(media, media_name, telemetry)
    intrinsics, prior, source = resolve_camera(params, calibration, meta)
    gps = meta.gps_source is not None and params.georeference != "off"
    if params.georeference == "required" and meta.gps_source is None:
        raise JobInputError("georeference 'required': the media has no GPS positions (no EXIF GPS in the photos, no "
                            "DJI telemetry for the video: upload its .SRT file as 'telemetry')")
    wants_map = (params.orthophoto, params.dsm)
    may_map = any(w is True for w in wants_map) or (gps and any(w is None for w in wants_map))
    sparse_end = _SPARSE_END if (params.dense or may_map) else 0.97
    model = reconstruct(media, intrinsics, params, lambda f, s: report(f * sparse_end / 0.97, s), media_name, prior)
    model.report["intrinsics"]["source"] = source
    out = Outcome(model, meta)
    t0 = time.perf_counter()
    report(sparse_end, "georeference")
    out.georef = _place(model, meta, params)
    out.ortho = params.orthophoto if params.orthophoto is not None else out.georef is not None
    out.dsm = params.dsm if params.dsm is not None else out.georef is not None
    mapping = out.ortho or out.dsm
    if mapping and out.georef is None:
        level = level_frame(model)
        apply(model, level.sim, level.describe())
        model.report["georeference"] = level.report()
        out.level = level
    out.timings["georeference"] = time.perf_counter() - t0
    if params.dense or mapping:
        t0 = time.perf_counter()
        end = _DENSE_END if mapping else 0.97
        out.dense = dense_pass(model, media, params, lambda f, s: report(sparse_end + (end - sparse_end) * f, s),
                               media_name)
        out.timings["dense"] = time.perf_counter() - t0
        model.report["dense"] = out.dense.report
        if mapping:
            out.products = _map(out, media, media_name, params,
                                lambda f, s: report(_DENSE_END + (_MAP_END - _DENSE_END) * f, s))
    model.report["timings_s"].update({k: round(v, 4) for k, v in out.timings.items()})
    return out


def _place(model: SparseModel, meta: FlightMeta, params: ReconstructionParams) -> Georeference | None:
    """Georeference the model in place when its frames have GPS positions (see the module docstring)."""
    if params.georeference == "off" or meta.gps_source is None:
        model.report["georeference"] = {"georeferenced": False, "frame": "the reconstruction's own (no GPS)"
                                        if meta.gps_source is None else "the reconstruction's own (georeference off)"}
        return None
    if meta.kind == "images":
        positions = frame_positions_from_exif(model, meta.photos)
    else:
        positions = frame_positions_from_telemetry(model, meta.telemetry)
    try:
        ref = georeference(model, positions, meta.gps_source, meta.altitude)
    except GeoreferenceError as exc:
        if params.georeference == "required":
            raise JobInputError(f"georeference: {exc}") from None
        model.report["georeference"] = {"georeferenced": False, "frame": "the reconstruction's own",
                                        "notes": [f"not georeferenced: {exc}"]}
        model.report["warnings"].append(f"not georeferenced: {exc}")
        return None
    apply(model, ref.sim, ref.describe())
    if params.gps_prior_m is not None:
        res = gps_adjust(model, ref, params.gps_prior_m, params.ba_iterations)
        ref.notes.append(f"bundle adjustment with the GPS as a {params.gps_prior_m:g} m prior on the camera centres "
                         f"({res.iterations} iterations, {res.termination})")
    model.report["georeference"] = ref.report(model)
    return ref


def _map(out: Outcome, media, media_name: str | None, params: ReconstructionParams, progress: ProgressFn):
    from .mapping import make_products

    ref = out.georef if out.georef is not None else out.level
    gsd = params.gsd_cm / 100.0 if params.gsd_cm is not None else None
    if gsd is not None and out.georef is None:
        out.model.report["warnings"].append("gsd_cm ignored: without GPS the map has no metric scale (the flight's own "
                                            "ground sampling distance is used)")
        gsd = None
    t0 = time.perf_counter()
    model = out.model
    # The orthophoto samples the frames as the lens saw them (one interpolation, through the lens model).
    refs = reference_frames(model.registered, params.dense_frames)
    native = model.intrinsics.scaled(1.0 / model.scale)
    raw = Intrinsics(native.fx, native.fy, native.cx, native.cy)
    frames = load_frames(media, raw, model.frame_index[refs], params.max_width, media_name)
    images = {int(f): frames[int(model.frame_index[f])] for f in refs if int(model.frame_index[f]) in frames}
    try:
        products = make_products(out.model, ref, out.dense.cloud.points, images, gsd, out.ortho, progress)
    except ValueError as exc:
        raise JobInputError(f"map products: {exc}") from None
    out.timings["map_products"] = time.perf_counter() - t0
    out.model.report["mapping"] = products.report
    return products


def write_outputs(out: Outcome, write: Callable[[str, bytes], None]) -> dict[str, float]:
    """Write every result of ``out`` through ``write(name, bytes)`` (report.json last, with these
    timings in it); returns seconds per group of outputs."""
    model = out.model
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    write("points.ply", ply_bytes(model.points, model.colors))
    for name, text in colmap_text(model).items():
        write(name, text.encode())
    write("trajectory.json", trajectory_json(model))
    if out.dense is not None:
        cloud = out.dense.cloud
        write("dense.ply", ply_bytes(cloud.points, cloud.colors, cloud.normals, cloud.views,
                                     "sweepcast dense reconstruction"))
        write("depth.zip", depth_zip(out.dense.names, out.dense.pngs))
    times["export"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    reg = model.registered
    dense = (out.dense.cloud.points, out.dense.cloud.colors) if out.dense is not None else None
    write("preview.png", preview_png(model.points, model.colors, model.R[reg], model.t[reg], dense=dense))
    times["preview"] = time.perf_counter() - t0
    if out.georef is not None or out.products is not None:
        times.update(_write_map_files(out, write))
    model.report["timings_s"].update({k: round(v, 4) for k, v in times.items()})
    write("report.json", json.dumps(model.report, indent=1).encode())
    return times


def _write_map_files(out: Outcome, write: Callable[[str, bytes], None]) -> dict[str, float]:
    from . import mapfiles

    times = {}
    epsg = out.georef.epsg if out.georef is not None else None
    origin = out.georef.origin if out.georef is not None else out.level.origin
    if out.georef is not None:
        t0 = time.perf_counter()
        cloud = out.dense.cloud if out.dense is not None else None
        pts, cols = (cloud.points, cloud.colors) if cloud is not None else (out.model.points, out.model.colors)
        write(LAZ_NAME, mapfiles.laz_bytes(pts, cols, epsg, origin))
        times["laz"] = time.perf_counter() - t0
    p = out.products
    if p is not None:
        t0 = time.perf_counter()
        if out.ortho and p.ortho is not None:
            write("orthophoto.tif", mapfiles.orthophoto_tif(p.ortho.rgba, p.grid, epsg, origin))
            write("orthophoto.png", mapfiles.orthophoto_png(p.ortho.rgba))
        if out.dsm:
            write("dsm.tif", mapfiles.dsm_tif(p.dsm, p.grid, epsg, origin))
            write("dsm.png", mapfiles.dsm_png(p.dsm))
        times["geotiff"] = time.perf_counter() - t0
    return times


def reconstruct_and_write(media: str | Path, params: ReconstructionParams, calibration: bytes | None,
                          telemetry: bytes | None, progress: ProgressFn, write: Callable[[str, bytes], None],
                          media_name: str | None = None) -> Outcome:
    """The whole reconstruction as the job and the command line run it: every stage (:func:`run_pipeline`, progress
    0 to 0.96), then every result written through ``write(name, bytes)`` (0.97, "export"; 1.0, "done")."""
    progress(0.0, "decode")
    out = run_pipeline(media, params, calibration, telemetry, progress, media_name)
    progress(0.97, "export")
    write_outputs(out, write)
    progress(1.0, "done")
    return out


def summary(out: Outcome) -> dict[str, Any]:
    """The job's short summary (its return value)."""
    rep = out.model.report
    s: dict[str, Any] = {
        "frames_registered": rep["frames"]["registered"],
        "frames_selected": rep["frames"]["selected"],
        "points": rep["points"],
        "reprojection_error_px": rep["reprojection_error_px"]["after_ba"]["mean"],
        "intrinsics": rep["intrinsics"]["source"],
        "focal_px": rep["intrinsics"]["fx"],
        "georeferenced": out.georef is not None,
        "results": out.result_names(),
    }
    if out.georef is not None:
        s["epsg"] = out.georef.epsg
    if out.dense is not None:
        s["dense_points"] = out.dense.report["points"]
    return s
