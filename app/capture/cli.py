"""The ``sweepcast live`` verb: its options, and the run (imported only when the verb runs: PyAV and OpenCV are not
needed to parse the other verbs)."""
from __future__ import annotations

import argparse
import os
import sys
import threading
from typing import TYPE_CHECKING


def main(args: argparse.Namespace) -> int:
    """The ``sweepcast live`` verb (``args`` from :func:`register`'s parser): 0 when stopped, 2 for a refusal."""
    from .live import LiveRun
    from .settings import CaptureSettings
    from .sources import SourceError
    from .uplink import UplinkError

    overrides = {k: v for k, v in {"tolerance_ms": args.tolerance_ms, "missing_seconds": args.missing_seconds,
                                   "jpeg_quality": args.quality}.items() if v is not None}
    try:
        settings = CaptureSettings(**overrides)
        run = LiveRun.open(args.server, args.rig, args.sources, args.key, args.offset, settings,
                           status_every=args.status_every, background=args.background)
    except (UplinkError, SourceError, ValueError) as exc:
        print(f"sweepcast live: {exc}", file=sys.stderr)
        return 2
    if sys.stdin is not None and sys.stdin.isatty():
        threading.Thread(target=_keys, args=(run,), daemon=True).start()
    run.status.event(f"{len(run.readers)} cameras of rig {args.rig} to {run.uplink.url}; Ctrl-C stops"
                     + ("; type b and Enter to send the next set as the empty scene" if sys.stdin and sys.stdin.isatty() else ""))
    try:
        run.run(args.seconds)
    except KeyboardInterrupt:
        run.stop()
    return 0

if TYPE_CHECKING:  # the run is built on demand: importing it loads PyAV and OpenCV
    from app.capture.live import LiveRun


def _keys(run: "LiveRun") -> None:
    for line in sys.stdin:
        if line.strip().lower() == "b":
            run.take_background()
            run.status.event("the next set goes as the empty scene (background)")


def register(sub) -> None:
    """Add the ``live`` verb to the ``sweepcast`` command's subparsers."""
    p = sub.add_parser("live", help="connect a rig's cameras (RTSP/RTMP/HTTP/UDP URLs, V4L2 devices, video files) to "
                                    "the service's live socket, building each frame set from one instant")
    p.add_argument("rig", metavar="RIG", help="the rig's id on the service (GET /v1/rigs)")
    p.add_argument("sources", metavar="SOURCE", nargs="+",
                   help="one per camera in rig order, or NAME=SOURCE: rtsp://..., rtmp://..., http(s)://..., "
                        "udp://..., /dev/videoN (V4L2), or a video file (played at its own frame rate, looped)")
    p.add_argument("--server", default=os.environ.get("SWEEPCAST_SERVER", "http://127.0.0.1:8000"),
                   help="the service (default http://127.0.0.1:8000; SWEEPCAST_SERVER)")
    p.add_argument("--key", default=os.environ.get("SWEEPCAST_KEY"), help="API key (SWEEPCAST_KEY)")
    p.add_argument("--tolerance-ms", type=float, dest="tolerance_ms",
                   help="largest spread of capture times in a set (default half the slowest camera's frame period; "
                        "SWEEPCAST_LIVE_TOLERANCE_MS)")
    p.add_argument("--missing-seconds", type=float, dest="missing_seconds",
                   help="a camera silent this long is reported missing and its last frame sent marked stale "
                        "(default 1; SWEEPCAST_LIVE_MISSING_SECONDS)")
    p.add_argument("--offset", action="append", default=[], metavar="NAME=MS",
                   help="add MS milliseconds to camera NAME's capture times (a camera whose clock runs 40 ms ahead: "
                        "NAME=-40); repeat per camera")
    p.add_argument("--quality", type=int, help="JPEG quality of the frames sent (default 90; SWEEPCAST_LIVE_JPEG_QUALITY)")
    p.add_argument("--background", action="store_true",
                   help="the first set is the empty scene: the service learns its background model (silhouettes) "
                        "from it")
    p.add_argument("--seconds", type=float, help="stop after this long (default: run until Ctrl-C)")
    p.add_argument("--status-every", type=float, dest="status_every",
                   help="seconds between status lines (default 1 on a terminal, else 10)")
    p.set_defaults(func=main)
