"""``sweepcast depth ...``: filter depth maps or YUV depth sequences, synthesise views.

    sweepcast depth filter IN OUT [--method auto] [--scale 2] [--texture T]
    sweepcast depth filter in.yuv out.yuv --width 960 --height 544 --scale 2 [--bits 8 --chroma 420]
    sweepcast depth synthesize --view L.png Ld.png --view R.png Rd.png --positions 0 1 --target-position 0.5
        --depth-units disparity --disparity-scale 4 --out V.png [--holes H.png]
    sweepcast depth synthesize --view ... --cameras cam.txt --names c1 c2 --target cV --z-near 1 --z-far 10 --out V.png
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from workers.common.cliutil import ProgressBar
from workers.common.jobctx import JobInputError
from workers.settings import WorkerSettings, worker_settings
from workers.common.validation import describe_errors

from . import io
from .errors import DepthInputError
from .job import run_depth_video
from .methods import METHODS
from .params import DepthFilterParams, SynthesizeParams
from .encoded import filter_depth_bytes, synthesize_bytes


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``depth`` verb with its ``filter`` and ``synthesize`` sub-verbs."""
    depth = subparsers.add_parser("depth", help="depth-map post-filtering and view synthesis")
    verbs = depth.add_subparsers(dest="depth_verb", required=True)

    f = verbs.add_parser("filter", help="upsample + post-filter a depth map (PNG/PGM) or a raw YUV sequence")
    f.add_argument("input", type=Path, help="depth map (.png/.pgm) or raw YUV sequence (.yuv)")
    f.add_argument("output", type=Path, help="output file (.png/.pgm, or .yuv for a sequence)")
    f.add_argument("--method", default="auto",
                   help=f"auto (wmf_dilation with --texture, else dilation) or one of {', '.join(METHODS)}")
    size = f.add_mutually_exclusive_group()
    size.add_argument("--scale", type=float, help="upsampling factor, e.g. 2")
    size.add_argument("--size", help="output size WIDTHxHEIGHT")
    f.add_argument("--upsampler", default="nearest", choices=["nearest", "bilinear"])
    f.add_argument("--window", type=int, default=3, help="dilation neighbourhood (odd pixels)")
    f.add_argument("--rule", default="midrange", choices=["midrange", "otsu"], help="foreground classification")
    f.add_argument("--min-contrast", type=int, default=0, help="levels; flatter windows are left alone")
    f.add_argument("--morph-window", type=int, default=3)
    f.add_argument("--morph-order", default="close", choices=["close", "open", "close-open", "open-close"])
    f.add_argument("--guide-window", type=int, default=9, help="weighted mode filter support (odd pixels)")
    f.add_argument("--texture", type=Path, help="texture image (or 8-bit 4:2:0 YUV for a sequence) for wmf")
    f.add_argument("--bits", type=int, help="bit depth (default: from the PNG; 8 for YUV)")
    f.add_argument("--larger-is-farther", action="store_true", help="levels use the opposite convention")
    f.add_argument("--width", type=int, help="YUV frame width")
    f.add_argument("--height", type=int, help="YUV frame height")
    f.add_argument("--chroma", default="400", choices=["400", "420"], help="YUV chroma format")
    f.set_defaults(func=_filter)

    s = verbs.add_parser("synthesize", help="render a virtual view from texture + depth views (DIBR)")
    s.add_argument("--view", nargs=2, action="append", required=True, metavar=("TEXTURE", "DEPTH"),
                   help="a source view; repeat for each view")
    s.add_argument("--out", type=Path, required=True, help="synthesised view (.png)")
    s.add_argument("--holes", type=Path, help="write the hole mask here (.png, 255 = unseen)")
    s.add_argument("--depth-units", default="inverse_depth", choices=["inverse_depth", "disparity"])
    s.add_argument("--z-near", type=float)
    s.add_argument("--z-far", type=float)
    s.add_argument("--disparity-scale", type=float, default=1.0, help="levels per pixel of disparity")
    s.add_argument("--bits", type=int)
    s.add_argument("--larger-is-farther", action="store_true")
    s.add_argument("--focal", type=float, help="focal length in pixels (rectified, inverse depth)")
    s.add_argument("--positions", type=float, nargs="+", help="camera x of each view (rectified)")
    s.add_argument("--target-position", type=float, help="camera x of the virtual view (rectified)")
    s.add_argument("--cameras", type=Path, help="MPEG/VSRS camera parameter file (general geometry)")
    s.add_argument("--names", nargs="+", help="camera names of the views in --cameras")
    s.add_argument("--target", help="camera name of the virtual view in --cameras")
    s.add_argument("--hole-fill", default="background", choices=["background", "inpaint", "none"])
    s.add_argument("--boundary-width", type=int, default=1)
    s.set_defaults(func=_synthesize)


def _filter(args: argparse.Namespace) -> int:
    fields: dict[str, Any] = {
        "method": args.method, "window": args.window, "rule": args.rule, "min_contrast": args.min_contrast,
        "morph_window": args.morph_window, "morph_order": args.morph_order, "guide_window": args.guide_window,
        "larger_is_nearer": not args.larger_is_farther, "upsampler": args.upsampler, "scale": args.scale,
    }
    try:
        if args.size:
            fields["out_width"], fields["out_height"] = _parse_size(args.size)
        if args.input.suffix.lower() == ".yuv":
            return _filter_yuv(args, fields)
        fields["bits"] = args.bits
        texture = args.texture.read_bytes() if args.texture else None
        out = filter_depth_bytes(args.input.read_bytes(), DepthFilterParams.model_validate(fields), texture)
        levels, _ = io.decode_depth(out)
        io.write_depth(args.output, levels)
    except (JobInputError, ValidationError, OSError) as exc:
        return _fail(exc)
    return 0


def _filter_yuv(args: argparse.Namespace, fields: dict[str, Any]) -> int:
    if args.width is None or args.height is None:
        raise DepthInputError("a .yuv input needs --width and --height")
    fields.update(width=args.width, height=args.height, bits=args.bits or 8, chroma=args.chroma)
    inputs = {"depth": args.input}
    if args.texture:
        inputs["texture"] = args.texture
    bar = ProgressBar("depth filter")
    report = args.output.with_suffix(".report.json")
    ctx = _FileContext(params=fields, paths=inputs, outputs={"filtered.yuv": args.output, "report.json": report},
                       bar=bar)
    try:
        summary = run_depth_video(ctx)
    finally:
        bar.close()
    print(f"{summary['frames']} frames -> {args.output} ({summary['output']['width']}x{summary['output']['height']}), "
          f"report {report}")
    return 0


def _synthesize(args: argparse.Namespace) -> int:
    try:
        fields: dict[str, Any] = {
            "depth_units": args.depth_units, "z_near": args.z_near, "z_far": args.z_far,
            "disparity_scale": args.disparity_scale, "bits": args.bits, "larger_is_nearer": not args.larger_is_farther,
            "hole_fill": args.hole_fill, "boundary_width": args.boundary_width,
        }
        views = [(Path(t).read_bytes(), Path(d).read_bytes()) for t, d in args.view]
        if args.cameras:
            fields.update(geometry="general", **_mpeg_cameras(args, views))
        else:
            fields.update(geometry="rectified", positions=args.positions, target_position=args.target_position,
                          focal_px=args.focal)
        image, holes = synthesize_bytes(views, SynthesizeParams.model_validate(fields))
        args.out.write_bytes(image)
        if args.holes:
            args.holes.write_bytes(holes)
    except (JobInputError, ValidationError, OSError) as exc:
        return _fail(exc)
    return 0


def _mpeg_cameras(args: argparse.Namespace, views: list[tuple[bytes, bytes]]) -> dict[str, Any]:
    if not args.names or not args.target:
        raise DepthInputError("--cameras needs --names (one per view) and --target")
    h, w = io.decode_texture(views[0][0]).shape[:2]
    cams = io.parse_mpeg_cameras(args.cameras.read_text(), w, h)
    missing = [n for n in [*args.names, args.target] if n not in cams]
    if missing:
        raise DepthInputError(f"camera(s) {', '.join(missing)} not in {args.cameras}; it has {', '.join(cams)}")

    def as_dict(name: str) -> dict[str, Any]:
        c = cams[name]
        return {"K": c.K.tolist(), "R": c.R.tolist(), "t": c.t.tolist()}

    return {"cameras": [as_dict(n) for n in args.names], "target_camera": as_dict(args.target)}


def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise DepthInputError(f"--size must look like 1920x1080, got {text!r}") from None
    return w, h


def _fail(exc: Exception) -> int:
    message = describe_errors(exc, "parameters") if isinstance(exc, ValidationError) else str(exc).splitlines()[0]
    print(f"error: {message}", file=sys.stderr)
    return 2


@dataclass
class _FileContext:
    """A JobContext over local files, so the CLI runs the same code as the service job."""

    params: dict[str, Any]
    paths: dict[str, Path]
    outputs: dict[str, Path]
    bar: ProgressBar
    job_id: str = "cli"
    kind: str = "depth.video"
    input_meta: dict[str, dict[str, Any]] = field(default_factory=dict)
    settings: WorkerSettings = field(default_factory=worker_settings)

    @property
    def inputs(self) -> dict[str, str]:
        return {k: str(v) for k, v in self.paths.items()}

    def input_path(self, name: str) -> Path:
        return self.paths[name]

    def read_input(self, name: str) -> bytes:
        return self.paths[name].read_bytes()

    def result_path(self, name: str) -> Path:
        return self.outputs[name]

    def write_result(self, name: str, data: bytes) -> None:
        self.result_path(name).write_bytes(data)

    def progress(self, fraction: float, stage: str) -> None:
        self.bar(fraction, stage)
