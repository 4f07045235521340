"""A whole drone reconstruction, as the job and the CLI run it: camera -> sparse model -> world frame ->
dense cloud -> map products -> files.

1. **Camera**: given intrinsics (the fast path), else a focal length from the media's metadata
   (:mod:`workers.drone.flightmeta`) that the bundle adjustment refines with radial distortion.
2. **Sparse model**: stills with GPS positions run as a survey (:mod:`workers.drone.survey`: tracks per block
   of photos, matches across flight lines, overlapping submodels mapped on their own and merged by their shared
   photos and the GPS); a video or stills without GPS as one sequence
   (:func:`workers.drone.reconstruction.reconstruct`).
3. **World frame**: GPS positions of the frames -> robust similarity into the local UTM zone
   (:mod:`workers.drone.georef`; optionally a bundle adjustment with the GPS as a prior); without GPS the
   reconstruction's own frame, levelled when a dense pass or map products are asked for.
4. **Dense cloud and map products**: a depth map per registered frame, then per ground tile the fused points
   and the DSM, then per ground tile the orthophoto (:mod:`workers.drone.survey.map_stages`).
5. **Files**: written from the tiles (:mod:`workers.drone.survey.products`).

Every stage's work runs through a :class:`~workers.fanout.FanOut` (Ray tasks across the cluster in a job, this
process on the command line) and keeps its outputs in a :class:`~workers.workarea.WorkArea`, so an attempt after
a lost worker goes on from the finished stages (:class:`~workers.drone.survey.stages.Stages`).
"""
from __future__ import annotations

import json
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from workers.common.jobctx import JobInputError
from workers.fanout import FanOut, InProcess
from workers.settings import worker_settings
from workers.workarea import InputRef, WorkArea

from .calibration import Intrinsics, from_values, parse_calibration
from .export import colmap_text, ply_bytes, trajectory_json
from .flightmeta import FlightMeta, centre_of, check_prior, read_flight_meta
from .frames import load_frames
from .georef import (Georeference, GeoreferenceError, apply, frame_positions_from_exif,
                     frame_positions_from_telemetry, georeference, gps_adjust, level_frame)
from .params import ReconstructionParams, max_dense_volume_from_env
from .preview import preview_png
from .reconstruction import ProgressFn, SparseModel, reconstruct
from .selfcal import FocalPrior, given_focal_prior
from .survey import products
from .survey.map_stages import DenseMap, dense_and_map
from .survey.photos import PhotoSource, stored_frame
from .survey.sparse_stages import SurveyUnplaced, is_survey, survey_sparse
from .survey.stages import Stages, fingerprint

RESULT_NAMES = ("points.ply", "cameras.txt", "images.txt", "points3D.txt", "trajectory.json", "report.json",
                "preview.png")
DENSE_RESULT_NAMES = ("dense.ply", "depth.zip")
ORTHO_RESULT_NAMES = ("orthophoto.tif", "orthophoto.png")
DSM_RESULT_NAMES = ("dsm.tif", "dsm.png")
LAZ_NAME = "points.laz"

# Progress: the share of the whole job each part ends at (with a dense pass; without one the sparse
# model takes it all).
_SPARSE_END = 0.4
_MAP_END = 0.96

ResultPath = Callable[[str], Path]
"""Where a result file is written: ``name -> path`` (the job's staging folder, the CLI's output folder)."""


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


@dataclass
class Outcome:
    """Everything one run produced (see :func:`run_pipeline`); its intermediate data stay in ``work`` (the dense
    cloud and the map as tiles) until :meth:`discard_work`."""

    model: SparseModel
    meta: FlightMeta
    work: WorkArea
    stages: Stages
    georef: Georeference | None = None
    dense: DenseMap | None = None
    level: Georeference | None = None
    """The arbitrary level frame a dense pass and map products use when there is no GPS."""
    ortho: bool = False
    dsm: bool = False
    owns_work: bool = False
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def maps(self) -> products.MapTiles | None:
        """The map's tiles (the DSM, the orthophoto, the dense points), while the work area is kept."""
        return self.dense.tiles if self.dense is not None and (self.ortho or self.dsm) else None

    def result_names(self) -> list[str]:
        """The files :func:`write_outputs` writes for this outcome."""
        names = list(RESULT_NAMES)
        if self.dense is not None:
            names += DENSE_RESULT_NAMES
        if self.georef is not None:
            names.append(LAZ_NAME)
        names += list(ORTHO_RESULT_NAMES if self.ortho else ()) + list(DSM_RESULT_NAMES if self.dsm else ())
        return names

    def discard_work(self) -> None:
        """Delete the intermediate data (the job's work area; the folder this run made for itself)."""
        self.work.clear()
        if self.owns_work:
            shutil.rmtree(Path(self.work.store.root), ignore_errors=True)


def run_pipeline(media: str | Path, params: ReconstructionParams, calibration: bytes | None = None,
                 telemetry: bytes | None = None, progress: ProgressFn | None = None,
                 media_name: str | None = None, fanout: FanOut | None = None, work: WorkArea | None = None,
                 media_ref: InputRef | None = None) -> Outcome:
    """Run every stage (module docstring) on ``media`` (a video, zip or folder of stills) with an optional
    calibration file's and telemetry (.SRT) file's bytes. ``progress(fraction, stage)`` goes from 0 to
    0.96. ``fanout``: where the stages' tasks run (default: this process); ``work``: where their outputs are kept
    (default: a folder of its own, deleted by :meth:`Outcome.discard_work`); ``media_ref``: the media as every node
    reads it (default: its path here). User-caused failures raise JobInputError."""
    report = (lambda f, s: progress(f, s)) if progress is not None else (lambda f, s: None)
    meta = read_flight_meta(media, media_name, telemetry)
    intrinsics, prior, source = resolve_camera(params, calibration, meta)
    gps = meta.gps_source is not None and params.georeference != "off"
    if params.georeference == "required" and meta.gps_source is None:
        raise JobInputError("georeference 'required': the media has no GPS positions (no EXIF GPS in the photos, no "
                            "DJI telemetry for the video: upload its .SRT file as 'telemetry')")
    owns = work is None
    work = work if work is not None else WorkArea.in_folder(tempfile.mkdtemp(prefix="sweepcast-work-"))
    media_ref = media_ref or InputRef(media_name or Path(media).name, path=str(media))
    stages = Stages(work, fanout or InProcess(), report,
                    fingerprint(params.model_dump_json(), _size(media), media_name, calibration, telemetry))
    wants_map = (params.orthophoto, params.dsm)
    may_map = any(w is True for w in wants_map) or (gps and any(w is None for w in wants_map))
    sparse_end = _SPARSE_END if (params.dense or may_map) else 0.97
    t0 = time.perf_counter()
    sharpness: dict[int, float] = {}
    survey = None
    if is_survey(meta, params):
        try:
            survey = survey_sparse(stages, media_ref, meta, intrinsics, prior, source, params, (0.0, sparse_end))
        except SurveyUnplaced as exc:
            if params.georeference == "required":
                raise JobInputError(f"georeference: {exc}") from None
            # Not a survey after all: the photos as one sequence, in their own frame, saying why.
    if survey is not None:
        model, georef, sharpness = survey.model, survey.georef, survey.sharpness
        model.report["survey"] = survey.report
        report(sparse_end, "georeference")
        model.report["georeference"] = georef.report(model)
    else:
        model, georef = stages.once("sparse model", lambda: _sequence(media, intrinsics, prior, source, params, meta,
                                                                      media_name, report, sparse_end), 0.0)
    out = Outcome(model, meta, work, stages, owns_work=owns)
    out.timings["sparse"] = time.perf_counter() - t0
    out.georef = georef
    out.ortho = params.orthophoto if params.orthophoto is not None else out.georef is not None
    out.dsm = params.dsm if params.dsm is not None else out.georef is not None
    mapping = out.ortho or out.dsm
    if (mapping or params.dense) and out.georef is None:
        level = level_frame(model)
        apply(model, level.sim, level.describe())
        model.report["georeference"] = level.report()
        out.level = level
    if params.dense or mapping:
        check_dense_volume(model, params)
        photos = _photos(stages, model, meta, media, media_ref, params, media_name, sparse_end)
        gsd = _gsd(out, params)
        out.dense = dense_and_map(stages, model, photos, params, out.georef is not None, out.ortho, gsd,
                                  worker_settings().max_map_pixels, sharpness, (sparse_end, _MAP_END))
        rec = stages.records
        out.timings["dense"] = sum(rec.get(k, {}).get("seconds", 0.0) for k in ("dense plan", "dense depth",
                                                                                "surface model"))
        if out.ortho:
            out.timings["orthophoto"] = rec["orthophoto"]["seconds"]
        model.report["dense"] = out.dense.dense
        if mapping:
            model.report["mapping"] = out.dense.mapping
    model.report["timings_s"].update({k: round(v, 4) for k, v in out.timings.items()})
    return out


def check_dense_volume(model: SparseModel, params: ReconstructionParams) -> None:
    """Raise JobInputError when an 'sgm' dense pass would hold more than ``$SWEEPCAST_MAX_DENSE_VOLUME`` cost-volume
    cells in one depth map (the streamed 'window' aggregation holds none)."""
    p = params
    if p.dense_aggregation != "sgm":
        return
    cells = int(round(model.width * p.dense_scale)) * int(round(model.height * p.dense_scale)) * p.dense_planes
    limit = max_dense_volume_from_env()
    if cells > limit:
        raise JobInputError(f"dense_aggregation 'sgm' would hold {cells:,} cost-volume cells (depth-map pixels x "
                            f"planes); the limit is {limit:,}: lower dense_scale or dense_planes, or use 'window'")


def _size(media: str | Path) -> int:
    path = Path(media)
    return sum(p.stat().st_size for p in path.iterdir()) if path.is_dir() else path.stat().st_size


def _sequence(media, intrinsics: Intrinsics, prior: FocalPrior | None, source: str, params: ReconstructionParams,
              meta: FlightMeta, media_name: str | None, report: ProgressFn, sparse_end: float
              ) -> tuple[SparseModel, Georeference | None]:
    """The sparse model of a video or of stills without GPS: one sequence, then its GPS placement if any."""
    model = reconstruct(media, intrinsics, params, lambda f, s: report(f * sparse_end / 0.97, s), media_name, prior)
    model.report["intrinsics"]["source"] = source
    report(sparse_end, "georeference")
    return model, _place(model, meta, params)


def _photos(stages: Stages, model: SparseModel, meta: FlightMeta, media, media_ref: InputRef,
            params: ReconstructionParams, media_name: str | None, at: float) -> PhotoSource:
    """Where the dense and map tasks read the frames: stills from the media itself; a video's registered frames
    decoded once here and kept in the work area at the working resolution (as the lens saw them)."""
    native = (int(round(model.width / model.scale)), int(round(model.height / model.scale)))
    working = (model.width, model.height)
    if meta.kind == "images":
        return PhotoSource(media_ref, working, native)

    def store() -> int:
        raw = model.intrinsics.scaled(1.0 / model.scale)
        frames = load_frames(media, Intrinsics(raw.fx, raw.fy, raw.cx, raw.cy),
                             model.frame_index[model.registered], params.max_width, media_name)
        from workers.common.images import encode_png

        name_of = {int(i): n for i, n in zip(model.frame_index, model.frame_name)}
        for index, image in frames.items():
            stages.work.put(stored_frame(name_of[int(index)]), encode_png(image, level=1))
        return len(frames)

    stages.once("store frames", store, at)
    return PhotoSource(media_ref, working, working, stored=True, work=stages.work)


def _gsd(out: Outcome, params: ReconstructionParams) -> float | None:
    """The orthophoto's cell asked for, in world units; None (the photos' own) without GPS, said in the report."""
    if params.gsd_cm is None:
        return None
    if out.georef is None:
        out.model.report["warnings"].append("gsd_cm ignored: without GPS the map has no metric scale (the photos' own "
                                            "ground sampling distance is used)")
        return None
    return params.gsd_cm / 100.0


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


def write_outputs(out: Outcome, result_path: ResultPath) -> dict[str, float]:
    """Write every result of ``out`` at ``result_path(name)`` (report.json last, with these timings and the stages'
    report in it); returns seconds per group of outputs."""
    model = out.model
    times: dict[str, float] = {}

    def write(name: str, data: bytes) -> None:
        result_path(name).write_bytes(data)

    t0 = time.perf_counter()
    write("points.ply", ply_bytes(model.points, model.colors))
    for name, text in colmap_text(model).items():
        write(name, text.encode())
    write("trajectory.json", trajectory_json(model))
    if out.dense is not None:
        products.write_dense_ply(out.dense.tiles, result_path("dense.ply"), out.dense.points)
        products.write_depth_zip(out.work, out.dense.depth_pngs, result_path("depth.zip"))
    times["export"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    reg = model.registered
    dense = out.dense.tiles.sample() if out.dense is not None else None
    write("preview.png", preview_png(model.points, model.colors, model.R[reg], model.t[reg], dense=dense))
    times["preview"] = time.perf_counter() - t0
    if out.georef is not None or out.ortho or out.dsm:
        times.update(_write_map_files(out, result_path))
    model.report["timings_s"].update({k: round(v, 4) for k, v in times.items()})
    model.report["stages"] = out.stages.report()
    write("report.json", json.dumps(model.report, indent=1).encode())
    return times


def _write_map_files(out: Outcome, result_path: ResultPath) -> dict[str, float]:
    from . import mapfiles

    times = {}
    epsg = out.georef.epsg if out.georef is not None else None
    origin = out.georef.origin if out.georef is not None else out.level.origin
    if out.georef is not None:
        t0 = time.perf_counter()
        if out.dense is not None:
            chunks = ((c["points"], c["colors"]) for c in out.dense.tiles.point_chunks())
            low = out.dense.low
        else:
            chunks = iter([(out.model.points, out.model.colors)])
            low = out.model.points.min(axis=0) if len(out.model.points) else np.zeros(3)
        mapfiles.write_laz(result_path(LAZ_NAME), chunks, epsg, origin, low)
        times["laz"] = time.perf_counter() - t0
    if out.dense is not None and (out.ortho or out.dsm):
        t0 = time.perf_counter()
        if out.ortho:
            products.write_orthophoto(out.dense.tiles, result_path("orthophoto.tif"), result_path("orthophoto.png"),
                                      epsg, origin)
        if out.dsm:
            products.write_dsm(out.dense.tiles, result_path("dsm.tif"), result_path("dsm.png"), epsg, origin)
        times["geotiff"] = time.perf_counter() - t0
    return times


def reconstruct_and_write(media: str | Path, params: ReconstructionParams, calibration: bytes | None,
                          telemetry: bytes | None, progress: ProgressFn, result_path: ResultPath,
                          media_name: str | None = None, fanout: FanOut | None = None, work: WorkArea | None = None,
                          media_ref: InputRef | None = None) -> Outcome:
    """The whole reconstruction as the job and the command line run it: every stage (:func:`run_pipeline`, progress
    0 to 0.96), then every result written at ``result_path(name)`` (0.97, "export"; 1.0, "done"), then the
    intermediate data deleted."""
    progress(0.0, "decode")
    out = run_pipeline(media, params, calibration, telemetry, progress, media_name, fanout, work, media_ref)
    progress(0.97, "export")
    write_outputs(out, result_path)
    out.discard_work()
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
        s["dense_points"] = out.dense.points
    if "mapping" in rep:
        s["coverage"] = {k: v for k, v in rep["mapping"]["coverage"].items() if k != "note"}
    return s
