"""Live ingest benchmark (issue 55): real-camera streams through ``sweepcast live`` into the service.

Ten RTSP cameras (``harness/rtsp_camera.py``: H.264 640x480 at 25 fps, triggered together within +-2 ms, each
stamping its frames with its own clock in RTCP sender reports) serve the demo rig's views of the studio with its
moving ball (pre-encoded, one IDR a second, looped: the cameras cost this machine only the sending). The capture
side (:class:`app.capture.live.LiveRun`, in this process: one reader thread per camera) sends frame sets to the
service (``python -m app serve``, its own process) while a viewer watches the live source. Measured over
``--seconds``:

- sets per second sent and acknowledged; the spread of capture times within each set (median, max);
- decode CPU per camera (each reader thread's CPU time: demuxing, decoding, stamping), the capture side's whole CPU
  (readers, JPEG encoding, assembly, uplink) and the service's (every process of it);
- capture-to-frame latency at a viewer: from a set's capture instant to the viewer's frame of it (same machine, one
  clock). ``ingest`` section: a closed-loop viewer rendered on the server at 320x240 (48 planes, coarse-to-fine,
  visual hull), p50/p95 and its fps. ``browser`` section: the viewer page rendering in headless Chromium at its
  default size (WebGL2: SwiftShader on a machine without a GPU, a CPU floor; ``--webgl gpu`` on a GPU machine),
  p50/p95 and fps, measured from BROWSER_SETTLE_S after its first frame;
- recovery: one camera stopped for ``--outage`` seconds, then started again: seconds from its stream's return to the
  first set sent with it fresh (``recovery`` section, three outages);
- reader threads against reader processes (``readers`` section, :mod:`benchmarks._live_readers`): the same cameras
  read by one thread per camera, by one process per camera handing frames over through shared memory, and by
  threads that convert to BGR as they decode, in turn, two rounds (``--seconds`` each, default 20): frames/s per
  camera and in all,
  CPU of the reader side and its reader processes, the age of the newest frame when a set is taken (p50/p95), peak
  resident memory. No service: the readers and the set assembler only.

Goals (issue 55): every set's spread <= half a frame period (20 ms); >= 15 sets/s with a viewer at >= 15 fps;
capture-to-frame p95 <= 250 ms in browser mode; a camera back within 5 s of its stream returning.

Run: ``python -m benchmarks.live_ingest [--only ingest,recovery,browser,readers] [--seconds 20] [--quick]``.
``--quick``: 4 cameras at 320x240 for 5 s (a check that it runs, not a figure).
"""
from __future__ import annotations

import collections
import io
import json
import os
import pickle
import statistics
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import cv2
import httpx
import numpy as np
import websockets.sync.client as wsclient

from app.capture.live import LiveRun
from app.capture.settings import CaptureSettings
from harness.proc import tree_cpu_seconds
from benchmarks import _live_readers
from benchmarks._report import Sections, md_table
from harness.rtsp_camera import Camera, RtspServer, encode_loop
from harness.servers import CHECKOUT_KERNEL_CACHE, serve_app
from workers.streaming.framing import pack_message, unpack_message

FPS = 25.0
LOOP_FRAMES = 50
SENSOR_NOISE = 2.0
"""Grey levels (sigma) of noise added to every frame before encoding, as a camera's sensor adds it: without it the
studio's still frames compress to ~100 bytes and cost nothing to decode, which no real camera's stream does."""
BIT_RATE = 1_500_000
"""Bits per second of a 640x480 camera (IP cameras stream 1-2 Mbit/s at that size; scaled by pixels for --quick)."""
VIEW = (320, 240)
PLANES = 48
BROWSER_SETTLE_S = 15.0
GOALS = {"spread_ms": 20.0, "sets_per_s": 15.0, "viewer_fps": 15.0, "browser_p95_ms": 250.0, "recovery_s": 5.0}

sections = Sections("live_ingest", __doc__)
sections.parser.add_argument("--seconds", type=float, help="measurement window per section, per trial in "
                                                           "readers (default 20; --quick 5)")
sections.parser.add_argument("--outage", type=float, default=5.0, help="seconds each camera outage lasts (default 5)")
sections.parser.add_argument("--webgl", choices=["swiftshader", "gpu"], default="swiftshader",
                             help="the browser section's WebGL (default swiftshader: a CPU floor)")
sections.parser.add_argument("--quick", action="store_true", help="4 cameras at 320x240, 5 s windows: a check that it "
                                                                 "runs")


# --- the rig, its pictures, its cameras --------------------------------------------------------------------------
def rig_and_streams(quick: bool) -> tuple[Any, list[bytes], list[list[bytes]]]:
    """The demo rig (10 cameras 640x480; --quick: 4 at 320x240), its empty-studio JPEGs (the background set) and per
    camera the H.264 access units of LOOP_FRAMES frames of the studio with its moving ball, with sensor noise (the
    rendered views are cached in the temp folder: rendering them takes minutes)."""
    from benchmarks.streaming import live_frame_sets
    from workers.streaming.demo import demo_rig

    cameras, size = (4, (320, 240)) if quick else (10, (640, 480))
    rig = demo_rig(cameras, size)
    cache = Path(tempfile.gettempdir()) / f"sweepcast-bench-live-ingest-{cameras}-{size[0]}.pickle"
    if cache.exists():  # the rendered views only: minutes to render, seconds to encode
        background, sets = pickle.loads(cache.read_bytes())
    else:
        background, sets = live_frame_sets(rig, 6)
        cache.write_bytes(pickle.dumps((background, sets)))
    rng = np.random.default_rng(0)
    streams = []
    for c in range(cameras):
        images = []
        for i in range(LOOP_FRAMES):
            clean = cv2.imdecode(np.frombuffer(sets[i % len(sets)][c], np.uint8), cv2.IMREAD_COLOR).astype(np.float32)
            images.append(np.clip(clean + rng.normal(0, SENSOR_NOISE, clean.shape), 0, 255).astype(np.uint8))
        streams.append(encode_loop(images, FPS, gop=int(FPS), bit_rate=BIT_RATE * size[0] * size[1] // (640 * 480)))
    return rig, background, streams


class Bench:
    """The service, a rig on it primed with its empty-studio set, its cameras and ``sweepcast live`` running."""

    def __init__(self, args: Any) -> None:
        self.args = args
        self.rig, self.background, self.streams = rig_and_streams(args.quick)
        self.seconds = args.seconds or (5.0 if args.quick else 20.0)

    def __enter__(self) -> "Bench":
        from workers.sweep.rig_io import rig_to_dict

        self._tmp = tempfile.TemporaryDirectory(prefix="sweepcast-bench-live-")
        env = {"SWEEPCAST_DATA_DIR": str(Path(self._tmp.name) / "data"), "SWEEPCAST_DEMO_RIG": "false",
               "SWEEPCAST_NUMBA_CACHE_DIR": str(CHECKOUT_KERNEL_CACHE)}
        self._served = serve_app(env, log=Path(self._tmp.name) / "server.log")
        self.app = self._served.__enter__()
        with httpx.Client(base_url=self.app.base, timeout=60) as http:
            self.rig_id = http.post("/v1/rigs", files={"files": ("rig.json", json.dumps(rig_to_dict(self.rig)).encode())}
                                    ).json()["id"]
        with wsclient.connect(f"{self.ws}/v1/rigs/{self.rig_id}/live", max_size=None) as live:
            live.recv()
            live.send(pack_message({"sizes": [len(j) for j in self.background], "background": True, "seq": 1},
                                   self.background))
            reply = json.loads(live.recv())
            if reply.get("type") != "ack":
                raise SystemExit(f"the service refused the background set: {reply}")
        w, h = self.rig.cameras[0].width, self.rig.cameras[0].height
        self.cameras = [Camera(c.name, w, h, fps=FPS, access_units=s, capture_jitter=0.002, seed=i)
                        for i, (c, s) in enumerate(zip(self.rig.cameras, self.streams))]
        self._rtsp = RtspServer(self.cameras).__enter__()
        self.log = io.StringIO()
        self.run = LiveRun.open(self.app.base, self.rig_id, [self._rtsp.url(c.name) for c in self.cameras],
                                settings=CaptureSettings(), out=self.log, status_every=5.0)
        self._thread = threading.Thread(target=self.run.run, daemon=True)
        self._thread.start()
        deadline = time.monotonic() + 60
        while not self.run.history or time.time() - self.run.history[0][0] < 3.0:  # sets flowing for 3 s
            if time.monotonic() > deadline:
                raise SystemExit(f"no frame sets within 60 s; sweepcast live said:\n{self.log.getvalue()[-3000:]}")
            time.sleep(0.2)
        return self

    def __exit__(self, *exc: object) -> None:
        self.run.stop()
        self._thread.join(20)
        self._rtsp.__exit__(None, None, None)
        self._served.__exit__(None, None, None)
        self._tmp.cleanup()

    @property
    def ws(self) -> str:
        return self.app.base.replace("http", "ws")

    def window(self, during=None) -> dict[str, Any]:
        """Sets, spreads and CPU over ``self.seconds`` (``during``: a callable run meanwhile on a thread, its result
        under "during")."""
        run = self.run
        cpu0 = [r.cpu_seconds for r in run.readers]
        sent0, acked0 = run.uplink.sent, run.uplink.acked
        server0, own0 = tree_cpu_seconds(self.app.proc.pid), time.process_time()
        t0, wall0 = time.monotonic(), time.time()
        out: dict[str, Any] = {}
        worker = threading.Thread(target=lambda: out.update(during=during(self.seconds))) if during else None
        if worker:
            worker.start()
        time.sleep(self.seconds)
        if worker:
            worker.join(self.seconds + 60)
        wall = time.monotonic() - t0
        spreads = [s for t, s, stale in list(run.history) if t >= wall0 and not any(stale)]
        return {
            **out, "seconds": wall, "sets_per_s": (run.uplink.sent - sent0) / wall,
            "acked_per_s": (run.uplink.acked - acked0) / wall, "dropped_by_uplink": run.uplink.dropped,
            "spread_p50_ms": statistics.median(spreads) * 1e3 if spreads else None,
            "spread_max_ms": max(spreads) * 1e3 if spreads else None,
            "decode_cpu_per_camera": [(r.cpu_seconds - c) / wall for r, c in zip(run.readers, cpu0)],
            "capture_side_cores": (time.process_time() - own0) / wall,
            "server_cores": (tree_cpu_seconds(self.app.proc.pid) - server0) / wall,
            "tolerance_ms": run.assembler.tolerance * 1e3, "refused": dict(run.uplink.errors),
            "service_ms": _service_ms(run.uplink),
        }


def _service_ms(uplink: Any) -> dict[str, float | None]:
    """Medians over the uplink's last 100 acknowledgements: the service's decode, its wait for the renderer's lock,
    the apply under it (ms, as each ack reports them), and send to ack at the client."""
    acks = list(uplink.acks)

    def median(key: str) -> float | None:
        values = [a[key] for a in acks if a.get(key) is not None]
        return round(statistics.median(values), 2) if values else None

    ack_ms = list(uplink.ack_ms)
    return {"decode_ms": median("decode_ms"), "lock_wait_ms": median("lock_wait_ms"), "apply_ms": median("apply_ms"),
            "send_to_ack_ms": round(statistics.median(ack_ms), 2) if ack_ms else None}


def server_viewer(bench: Bench, seconds: float) -> dict[str, Any]:
    """A closed-loop viewer rendered on the server (VIEW, PLANES): fps, and capture-to-frame latency per frame (now
    minus its set's capture instant)."""
    latencies, frames, levels, ms = [], 0, collections.Counter(), []
    with wsclient.connect(f"{bench.ws}/v1/rigs/{bench.rig_id}/view?source=live", max_size=None) as ws:
        while json.loads(ws.recv())["type"] != "ready":
            pass
        t_end, i = time.monotonic() + seconds, 0
        while time.monotonic() < t_end:
            i += 1
            ws.send(json.dumps({"id": i, "frame": "live", "width": VIEW[0], "height": VIEW[1], "planes": PLANES,
                                "orbit": {"azimuth": -40 + (i * 1.5) % 80}, "quality": 80}))
            while isinstance(reply := ws.recv(), str):
                if json.loads(reply).get("type") == "error":
                    raise SystemExit(f"the viewer got an error: {reply}")
            header, _ = unpack_message(reply)
            levels[str(header.get("quality"))] += 1
            if header.get("render_ms") is not None:
                ms.append(header["render_ms"])
            if header.get("captured") is not None:
                latencies.append((time.time() - header["captured"]) * 1e3)
            frames += 1
    return {"fps": frames / seconds, "capture_to_frame_p50_ms": float(np.percentile(latencies, 50)),
            "capture_to_frame_p95_ms": float(np.percentile(latencies, 95)), "frames": frames, "levels": dict(levels),
            "render_ms_p50": float(np.median(ms)) if ms else None}


@sections.section("ingest", "ten RTSP cameras to the service with a server-rendered viewer: sets/s, spread, CPU, "
                            "capture-to-frame latency", keys=("setup", "ingest"))
def ingest(args: Any) -> dict[str, Any]:
    with Bench(args) as bench:
        alone = bench.window()
        viewed = bench.window(lambda s: server_viewer(bench, s))
        setup = {"cameras": len(bench.rig), "size": f"{bench.rig.cameras[0].width}x{bench.rig.cameras[0].height}",
                 "fps": FPS, "view": f"{VIEW[0]}x{VIEW[1]}", "planes": PLANES, "seconds": bench.seconds,
                 "bytes_per_frame": float(np.mean([len(u) for s in bench.streams for u in s]))}
    print(f"ingest alone: {alone}\nwith a viewer: {viewed}")
    return {"setup": setup, "ingest": {"alone": alone, "viewer": viewed}}


@sections.section("recovery", "one camera stopped for --outage seconds, three times: seconds until it is in the sets "
                              "again after its stream returns", keys=("recovery",))
def recovery(args: Any) -> dict[str, Any]:
    times = []
    with Bench(args) as bench:
        for n in range(3):
            cam = bench.cameras[(3 + n) % len(bench.cameras)]
            index = bench.cameras.index(cam)
            cam.stop()
            time.sleep(args.outage)
            cam.start(bench._rtsp.epoch)
            back = time.time()
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:
                fresh = [t for t, _, stale in list(bench.run.history) if t > back and not stale[index]]
                if fresh:
                    times.append(fresh[0] - back)
                    break
                time.sleep(0.05)
            else:
                times.append(None)
            time.sleep(2.0)
    print(f"recovery: {times}")
    return {"recovery": {"outage_s": args.outage, "seconds": times}}


@sections.section("browser", "the viewer page rendering the live stream in headless Chromium during ingest: "
                             "capture-to-frame latency and fps", keys=("browser",))
def browser(args: Any) -> dict[str, Any]:
    from harness.browser import chromium

    with Bench(args) as bench, chromium(args.webgl) as chrome:
        page = chrome.new_page(viewport={"width": 1280, "height": 900})
        page.goto(f"{bench.app.base}/viewer/?rig={bench.rig_id}&source=live&render=browser")
        page.wait_for_function("() => viewerState.ready && viewerState.received > 0", timeout=300_000)
        gpu = page.evaluate("viewerState.gpu")
        # the sets that queued in the browser's socket while its shaders compiled (seconds on SwiftShader) are worked
        # off newest-first, which takes a few draws: measured after that
        time.sleep(BROWSER_SETTLE_S)
        page.evaluate("viewerState.captureLatencies = []; viewerState.received = 0")
        t0 = time.monotonic()
        time.sleep(bench.seconds)
        latencies = page.evaluate("viewerState.captureLatencies")
        frames = page.evaluate("viewerState.received")
        wall = time.monotonic() - t0
        mode = page.evaluate("viewerState.mode")
    if not latencies:
        raise SystemExit("the browser drew no live frame within the window: give --seconds more")
    out = {"webgl": args.webgl, "gpu": gpu, "mode": mode, "fps": frames / wall,
           "capture_to_frame_p50_ms": float(np.percentile(latencies, 50)),
           "capture_to_frame_p95_ms": float(np.percentile(latencies, 95)), "frames": frames}
    print(f"browser: {out}")
    return {"browser": out}


@sections.section("readers", "reader threads against reader processes, alternately: frames/s, CPU, the newest "
                             "frame's age when a set is taken, peak memory", keys=("readers",))
def readers(args: Any) -> dict[str, Any]:
    rig, _, streams = rig_and_streams(args.quick)
    return _live_readers.measure(rig, streams, FPS, args.seconds or (5.0 if args.quick else 20.0))


def markdown(results: dict[str, Any], kept: list[str]) -> str:
    st = results.get("setup", {})
    md = []
    if any(k in results for k in ("setup", "browser", "recovery")):  # the sections that run the service
        md.append(
            f"RTSP cameras as issue 55 asks ({'ten' if st.get('cameras') == 10 else 'not ten: a --quick run'}): "
            f"{st.get('cameras', '?')} cameras {st.get('size', '?')} H.264 at "
            f"{st.get('fps', FPS):g} fps (harness/rtsp_camera.py: triggered together +-2 ms, each stamping its "
            "frames with its own clock in RTCP sender reports; the demo studio with its moving ball, pre-encoded, one "
            "IDR a second, sensor noise of sigma 2 grey levels, 1.5 Mbit/s at 640x480: "
            f"{st.get('bytes_per_frame', 0) / 1e3:.1f} KB per frame), read by `sweepcast live` (one reader thread "
            "per camera, in the benchmark's process) and sent to the service (`python -m app serve`, its own process) "
            "on the same 2 cores. Reader CPU per camera: each reader thread's CPU time (demuxing, decoding, stamping; "
            "its frames are converted and JPEG-encoded only when a set uses them, counted in the capture side's "
            "cores, which also hold the simulated cameras' sending).")
    rows = []
    for name, key in (("ingest alone", "alone"), (f"ingest + a server-rendered viewer {st.get('view', '')}", "viewer")):
        r = results.get("ingest", {}).get(key)
        if not r:
            continue
        v = r.get("during", {})
        rows.append([name, r["sets_per_s"], r["acked_per_s"], r["spread_p50_ms"], r["spread_max_ms"],
                     statistics.mean(r["decode_cpu_per_camera"]) * 100, r["capture_side_cores"], r["server_cores"],
                     v.get("fps", "-"), v.get("capture_to_frame_p50_ms", "-"), v.get("capture_to_frame_p95_ms", "-")])
    if rows:
        md += ["", "### Ingest", "", md_table(
            ["configuration", "sets/s sent", "sets/s acked", "spread p50 ms", "spread max ms",
             "reader CPU per camera (% of a core)", "capture side cores", "service cores", "viewer fps",
             "capture-to-frame p50 ms", "p95 ms"], rows)]
        svc = [[name, *(r.get("service_ms", {}).get(k, "-") for k in ("decode_ms", "lock_wait_ms", "apply_ms",
                                                                      "send_to_ack_ms"))]
               for name, key in (("ingest alone", "alone"), ("with the viewer", "viewer"))
               if (r := results.get("ingest", {}).get(key)) and r.get("service_ms")]
        if svc:
            md += ["", "Where a set's time goes in the service (medians of the last 100 acknowledgements: decoding its "
                   "JPEGs, waiting for the renderer's lock while a view is drawn, applying it under the lock: "
                   "background model, silhouettes, the renderer's frames), and from send to ack at the client:", "",
                   md_table(["configuration", "decode ms", "lock wait ms", "apply ms", "send to ack ms"], svc)]
    b = results.get("browser")
    if b:
        md += ["", f"### Browser-rendered viewer ({b['webgl']}: {b['gpu']})", "",
               md_table(["mode", "fps", "capture-to-frame p50 ms", "p95 ms", "frames"],
                        [[b["mode"], b["fps"], b["capture_to_frame_p50_ms"], b["capture_to_frame_p95_ms"], b["frames"]]])]
        if b["webgl"] == "swiftshader":
            md.append("\nSwiftShader renders WebGL2 on this machine's CPU: a floor, not a GPU's figure.")
    rec = results.get("recovery")
    if rec:
        md += ["", f"### Recovery: a camera's stream stopped for {rec['outage_s']:g} s, three times", "",
               "Seconds from its stream's return to the first set sent with it fresh: "
               + ", ".join("never (30 s)" if s is None else f"{s:.2f}" for s in rec["seconds"]) + "."]
    if results.get("readers"):
        md += _live_readers.markdown(results["readers"])
    goals = goal_lines(results)
    md += ["", "### Goals", "", *goals] if goals else []
    return "\n".join(md) + "\n"


def goal_lines(results: dict[str, Any]) -> list[str]:
    lines = []
    viewed = results.get("ingest", {}).get("viewer")
    if viewed:
        ok = viewed["spread_max_ms"] is not None and viewed["spread_max_ms"] <= GOALS["spread_ms"]
        lines.append(f"- every set's spread <= {GOALS['spread_ms']:g} ms (half a frame period): largest "
                     f"{viewed['spread_max_ms']:.1f} ms: **{'met' if ok else 'not met'}**")
        fps = viewed.get("during", {}).get("fps", 0.0)
        ok = viewed["sets_per_s"] >= GOALS["sets_per_s"] and fps >= GOALS["viewer_fps"]
        lines.append(f"- >= {GOALS['sets_per_s']:g} sets/s with a viewer at >= {GOALS['viewer_fps']:g} fps: "
                     f"{viewed['sets_per_s']:.1f} sets/s, viewer {fps:.1f} fps: **{'met' if ok else 'not met'}**"
                     + ("" if ok else f" (the service used {viewed['server_cores']:.2f} cores and the capture side "
                                      f"{viewed['capture_side_cores']:.2f} of this machine's 2)"))
    b = results.get("browser")
    if b:
        ok = b["capture_to_frame_p95_ms"] <= GOALS["browser_p95_ms"]
        lines.append(f"- capture-to-frame p95 <= {GOALS['browser_p95_ms']:g} ms in browser mode: "
                     f"{b['capture_to_frame_p95_ms']:.0f} ms ({b['webgl']}): **{'met' if ok else 'not met'}**")
    rec = results.get("recovery")
    if rec:
        ok = all(s is not None and s <= GOALS["recovery_s"] for s in rec["seconds"])
        lines.append(f"- a camera back within {GOALS['recovery_s']:g} s of its stream returning: "
                     f"{'met' if ok else 'not met'}")
    return lines


if __name__ == "__main__":
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    raise SystemExit(sections.main(markdown))
