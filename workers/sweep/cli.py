"""``sweepcast render``: one virtual view from a calibrated rig and its images."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np
from pydantic import ValidationError

from workers.camera import CameraError
from workers.common.cliutil import format_table
from workers.common.validation import describe_errors

from .overlays import depth_image, regions_image
from .renderer import RenderOptions, SweepRenderer
from .rig import Rig, RigError
from .rig_io import find_image, load_images, load_rig
from .virtual import parse_pose

_ERR_PREFIX = "sweepcast render: error:"


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``render`` sub-command."""
    p = subparsers.add_parser(
        "render", help="render a virtual view from a calibrated camera rig (plane sweep)",
        description="Plane-sweep rendering of a virtual view (Kojima & Fujimoto). RIG is our JSON, an OpenCV "
                    "YAML/XML, a Middlebury *_par.txt, a COLMAP text folder or a rectified Middlebury folder.",
    )
    p.add_argument("--rig", required=True, help="calibration file or folder")
    p.add_argument("--images", required=True, help="folder with one image per rig camera")
    p.add_argument("--pose", required=True,
                   help="NAME | A:B:S (between rig cameras) | lookat:EX,EY,EZ:TX,TY,TZ[:UX,UY,UZ] | camera.json")
    p.add_argument("--method", default="kojima", choices=["kojima", "kojima_k", "nearest", "ulr", "global"],
                   help="colour weighting: kojima (two-camera boundary blending, the paper), kojima_k (every "
                        "camera within D_bnd of the nearest one), nearest, ulr, global (default: kojima)")
    p.add_argument("--out", required=True, help="output image (PNG/JPEG)")
    p.add_argument("--depth-out", help="depth map: .npy (float32 metres, inf = none) or an image (colour picture)")
    p.add_argument("--regions-out",
                   help="region map picture (one-camera regions by camera, two cameras blended black, three or more red)")
    p.add_argument("--backgrounds", help="folder of empty-scene images (same names): silhouettes by background subtraction")
    p.add_argument("--silhouettes", help="folder of silhouette masks (same names, non-zero = object)")
    p.add_argument("--size", help="virtual image size WxH (default: the pose camera's, 640x480 for lookat)")
    p.add_argument("--fov", type=float, default=50.0, help="horizontal field of view for lookat poses (degrees)")
    p.add_argument("--planes", type=int, default=RenderOptions.model_fields["planes"].default)
    p.add_argument("--near", type=float, help="nearest plane depth (default: the rig's depth range or a guess)")
    p.add_argument("--far", type=float, help="farthest plane depth")
    p.add_argument("--d-bnd", type=float, help="D_bnd (kojima, kojima_k; default: from the camera spacing)")
    p.add_argument("--k", type=int, default=RenderOptions.model_fields["k"].default, help="cameras blended (ulr)")
    p.add_argument("--no-hull", action="store_true", help="do not cull with the visual hull")
    p.add_argument("--coarse-to-fine", action="store_true", help="half-resolution full sweep, then a narrow window")
    p.add_argument("--aggregation", default=RenderOptions.model_fields["aggregation"].default,
                   choices=["none", "window", "sgm"],
                   help="choose each pixel's depth alone (none: fastest), on the variance over a window, or that "
                        "plus semi-global smoothing along scanlines (sgm)")
    p.add_argument("--window", type=int, default=RenderOptions.model_fields["window"].default,
                   help="aggregation window radius in pixels (the window is 2r+1 square)")
    p.add_argument("--truncated", type=float, metavar="T", help="truncated-variance cost with threshold T (0..255)")
    p.add_argument("--visibility", action=argparse.BooleanOptionalAction,
                   default=RenderOptions.model_fields["visibility"].default,
                   help="colour each pixel only from the cameras its surface point is not hidden from by a nearer "
                        "surface of the view (per-camera z-buffers of the rendered depth; default: on with "
                        "--occlusions fill)")
    p.add_argument("--visibility-tolerance", type=float,
                   default=RenderOptions.model_fields["visibility_tolerance"].default,
                   help="relative depth margin of the visibility test (0.03: hidden when something is 3%% nearer)")
    p.add_argument("--occlusions", default=RenderOptions.model_fields["occlusions"].default, choices=["keep", "fill"],
                   help="fill the pixels whose depth the cameras do not confirm (half-occluded strips next to depth "
                        "edges) with the farther neighbouring depth along the scanline (fill), or keep the searched "
                        "depth (keep)")
    p.set_defaults(func=run_render)


def run_render(args: argparse.Namespace) -> int:
    """Handler of ``sweepcast render``; returns the exit code (2 for bad input)."""
    try:
        size = _parse_size(args.size) if args.size else None
        rig = load_rig(args.rig)
        images = load_images(rig, args.images)
        backgrounds = load_images(rig, args.backgrounds) if args.backgrounds else None
        silhouettes = _load_masks(rig, args.silhouettes) if args.silhouettes else None
        virtual = parse_pose(args.pose, rig, size=size, fov_deg=args.fov)
        renderer = SweepRenderer(rig, images, backgrounds=backgrounds, silhouettes=silhouettes)
        options = RenderOptions(
            method=args.method, d_bnd=args.d_bnd, k=args.k, planes=args.planes, near=args.near, far=args.far,
            visual_hull=False if args.no_hull else None, coarse_to_fine=args.coarse_to_fine,
            consistency="truncated" if args.truncated is not None else "variance",
            truncation=args.truncated if args.truncated is not None else 30.0,
            aggregation="none" if args.truncated is not None else args.aggregation, window=args.window,
            visibility=args.visibility, visibility_tolerance=args.visibility_tolerance, occlusions=args.occlusions,
        )
        result = renderer.render(virtual, options)
    except (RigError, CameraError, ValidationError, ValueError) as e:
        print(f"{_ERR_PREFIX} {_one_line(e)}", file=sys.stderr)
        return 2
    outputs = [(args.out, result.image)]
    if args.depth_out and not args.depth_out.endswith(".npy"):
        outputs.append((args.depth_out, depth_image(result.depth)))
    if args.regions_out:
        outputs.append((args.regions_out, regions_image(result.regions, result.primary)))
    for path, img in outputs:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(path, img):
            print(f"{_ERR_PREFIX} cannot write {path} (unknown image extension or unwritable folder)", file=sys.stderr)
            return 2
    if args.depth_out and args.depth_out.endswith(".npy"):
        np.save(args.depth_out, result.depth)
    found = np.isfinite(result.depth)
    rows = [[k.removesuffix("_ms"), f"{v:.1f}"] for k, v in result.timings.items()]
    print(f"{virtual.width}x{virtual.height} view, {len(result.planes)} planes, "
          f"depth found on {found.mean():.1%} of pixels, written to {args.out}")
    print(format_table(["stage", "ms"], rows))
    return 0


def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise RigError(None, "size", f"'{text}' is not WxH (e.g. 640x480)") from None
    if not (0 < w <= 8192 and 0 < h <= 8192):
        raise RigError(None, "size", f"{w}x{h} is out of range")
    return w, h


def _load_masks(rig: Rig, folder: str) -> list[np.ndarray]:
    out = []
    for cam, name in zip(rig.cameras, rig.image_files):
        p = find_image(Path(folder), name)
        m = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) if p is not None else None
        if m is None:
            raise RigError(cam.name, "silhouette", f"no readable mask {name!r} in {folder}")
        out.append(m > 0)
    return out


def _one_line(e: Exception) -> str:
    if isinstance(e, ValidationError):
        return describe_errors(e)
    return str(e).splitlines()[0]
