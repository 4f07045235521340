"""The benchmark's RTSP cameras in a process of their own, so that the CPU and memory of the reader designs measured
beside them (``benchmarks/live_ingest.py``, section ``readers``) hold none of the cameras' sending.

``python -m benchmarks._camera_process CAMERAS.pickle``: the pickle holds ``{"names": [str], "width": int,
"height": int, "fps": float, "access_units": [[bytes]]}`` (per camera its pre-encoded H.264 loop,
:func:`harness.rtsp_camera.encode_loop`). Serves them as :class:`harness.rtsp_camera.RtspServer` does (triggered
together within +-2 ms, RTCP sender reports on each camera's clock), prints the server's base URL
(``rtsp://127.0.0.1:PORT``) on one line, and serves until its standard input closes.
"""
from __future__ import annotations

import pickle
import sys
from pathlib import Path

from harness.rtsp_camera import Camera, RtspServer

CAPTURE_JITTER_S = 0.002


def main(path: str) -> None:
    spec = pickle.loads(Path(path).read_bytes())
    cameras = [Camera(name, spec["width"], spec["height"], fps=spec["fps"], access_units=units,
                      capture_jitter=CAPTURE_JITTER_S, seed=i)
               for i, (name, units) in enumerate(zip(spec["names"], spec["access_units"]))]
    with RtspServer(cameras) as server:
        print(f"rtsp://127.0.0.1:{server.port}", flush=True)
        sys.stdin.read()  # the benchmark closes it to stop the cameras


if __name__ == "__main__":
    main(sys.argv[1])
