"""``sweepcast reconstruct VIDEO [--intrinsics fx,fy,cx,cy] [--orthophoto] [--out DIR]``: drone video ->
point cloud, and for a georeferenced flight a map.

VIDEO may also be a zip or a folder of ordered still images. Without intrinsics the camera is
self-calibrated (EXIF, DJI telemetry or a default field of view). The results are the job's
(:mod:`workers.drone.pipeline`): points.ply, cameras.txt, images.txt, points3D.txt, trajectory.json,
report.json, preview.png; with ``--dense`` dense.ply and depth.zip; georeferenced points.laz; with map
products orthophoto.tif/.png and dsm.tif/.png.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pydantic import ValidationError

from workers.common.cliutil import ProgressBar, format_table
from workers.common.jobctx import JobInputError
from workers.common.validation import describe_errors
from workers.workarea import WorkArea

from .params import ReconstructionParams
from .pipeline import reconstruct_and_write


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``reconstruct`` verb."""
    p = subparsers.add_parser("reconstruct", help="3D reconstruction (points + camera path) from a drone video")
    p.add_argument("video", type=Path, help="video file, or a zip / folder of ordered images")
    p.add_argument("--intrinsics", help="fx,fy,cx,cy in pixels of the video's resolution (default: self-calibrated "
                                        "from EXIF, DJI telemetry or a 72 degree field of view)")
    p.add_argument("--calibration", type=Path, help="calibration file (OpenCV YAML/XML/JSON, COLMAP cameras.txt)")
    p.add_argument("--distortion", help="OpenCV distortion k1,k2,p1,p2[,k3]: frames are undistorted first")
    p.add_argument("--out", type=Path, default=Path("reconstruction"), help="output folder (default ./reconstruction)")
    p.add_argument("--frame-step", type=int, help="use every k-th frame (default: adaptive by motion)")
    p.add_argument("--matcher", choices=["fast_lk", "sift"], default="fast_lk")
    p.add_argument("--max-frames", type=int, help="most frames to track")
    p.add_argument("--max-width", type=int, help="downscale wider frames to this width")
    p.add_argument("--dense", action="store_true", default=None,
                   help="also a dense reconstruction: dense.ply (points, normals, colours) and depth.zip")
    p.add_argument("--dense-planes", type=int, help="depth planes per depth map (default 128)")
    p.add_argument("--dense-scale", type=float,
                   help="depth-map resolution as a fraction of the working one (default 1)")
    p.add_argument("--telemetry", type=Path, help="the video's DJI .SRT telemetry file (GPS per frame)")
    p.add_argument("--georeference", choices=["auto", "required", "off"],
                   help="place the result in the local UTM zone from GPS (default auto: when the media has GPS)")
    p.add_argument("--orthophoto", action=argparse.BooleanOptionalAction, default=None,
                   help="orthophoto.tif (COG) + orthophoto.png (default: on for a georeferenced flight)")
    p.add_argument("--dsm", action=argparse.BooleanOptionalAction, default=None,
                   help="dsm.tif (float32 heights) + dsm.png (default: on for a georeferenced flight)")
    p.add_argument("--gsd-cm", type=float, help="ground sampling distance of the orthophoto, cm per pixel (default: "
                                                "the photos' own)")
    p.add_argument("--work", type=Path, help="keep the intermediate data in this folder (a run cut short goes on "
                                             "from its finished stages when started again with the same folder; "
                                             "deleted on success)")
    p.add_argument("--params", help="further ReconstructionParams as JSON, e.g. '{\"outlier_threshold\": 3}'")
    p.set_defaults(func=_reconstruct)


def _numbers(text: str, what: str) -> list[float]:
    try:
        return [float(v) for v in text.replace(" ", "").split(",") if v]
    except ValueError:
        raise JobInputError(f"{what} must be comma-separated numbers, got {text!r}") from None


def _params(args: argparse.Namespace) -> ReconstructionParams:
    fields: dict = json.loads(args.params) if args.params else {}
    if args.intrinsics:
        values = _numbers(args.intrinsics, "--intrinsics")
        if len(values) != 4:
            raise JobInputError(f"--intrinsics needs four numbers fx,fy,cx,cy, got {len(values)}")
        fields.update(zip(("fx", "fy", "cx", "cy"), values))
    if args.distortion:
        fields["distortion"] = _numbers(args.distortion, "--distortion")
    for name in ("frame_step", "matcher", "max_frames", "max_width", "dense", "dense_planes", "dense_scale",
                 "georeference", "orthophoto", "dsm", "gsd_cm"):
        if getattr(args, name) is not None:
            fields[name] = getattr(args, name)
    return ReconstructionParams.model_validate(fields)


def _reconstruct(args: argparse.Namespace) -> int:
    bar = None
    try:
        params = _params(args)
        calib = args.calibration.read_bytes() if args.calibration else None
        telemetry = args.telemetry.read_bytes() if args.telemetry else None
        args.out.mkdir(parents=True, exist_ok=True)
        bar = ProgressBar("reconstruct")
        work = WorkArea.in_folder(args.work) if args.work is not None else None
        out = reconstruct_and_write(args.video, params, calib, telemetry, bar, lambda name: args.out / name,
                                    work=work)
    except (JobInputError, ValidationError, json.JSONDecodeError, OSError) as exc:
        if bar is not None:
            bar.close()
        message = describe_errors(exc) if isinstance(exc, ValidationError) else str(exc)
        print(f"sweepcast reconstruct: {message}", file=sys.stderr)
        return 2
    bar.close()
    rep = out.model.report
    intr = rep["intrinsics"]
    err = rep["reprojection_error_px"]
    rows = [
        ["frames decoded / selected", f"{rep['frames']['decoded']} / {rep['frames']['selected']}"],
        ["keyframes registered", f"{rep['frames']['keyframes_registered']} / {rep['frames']['keyframes']}"],
        ["frames registered", rep["frames"]["registered"]],
        ["tracks", rep["tracks"]["count"]],
        ["inlier ratio (mean per pair)", f"{rep['matcher']['inlier_ratio_mean']:.3f}"],
        ["points", rep["points"]],
        ["reprojection error before BA (mean, px)", _fmt(err["before_ba"]["mean"])],
        ["reprojection error after BA (mean, px)", _fmt(err["after_ba"]["mean"])],
        ["intrinsics", f"{intr['source']}: f {intr['fx']:.1f} px"
                       + (f", k1 {intr['distortion'][0]:.4f} k2 {intr['distortion'][1]:.4f}" if intr["distortion"] else "")],
        ["world frame", rep["georeference"]["frame"]],
    ]
    if out.dense is not None:
        d = out.dense.dense
        rows += [["dense depth maps", d["depth_maps"]], ["dense points", d["points"]],
                 ["dense: consistent in >= 3 views", _fmt(d["views_per_point"]["at_least_3"])],
                 ["dense: seconds per depth map (median)", _fmt(d["seconds_per_depth_map"]["median"])]]
    if "mapping" in rep:
        m = rep["mapping"]
        rows.append(["orthophoto grid", f"{m['grid']['width']} x {m['grid']['height']} cells of "
                                        f"{m['gsd'] * 100:.1f} cm" if m["gsd_unit"] == "m" else
                     f"{m['grid']['width']} x {m['grid']['height']} cells ({m['gsd_unit']})"])
        rows.append(["coverage of the photos' footprints (DSM / orthophoto)",
                     f"{_fmt(m['coverage'].get('dsm'))} / {_fmt(m['coverage'].get('orthophoto'))}"])
    rows.append(["total time (s)", f"{sum(rep['timings_s'].values()):.1f}"])
    print(format_table(["", "value"], rows))
    print(f"results in {args.out}/")
    return 0


def _fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.3f}"
