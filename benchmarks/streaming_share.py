"""Viewers sharing one session: fair share among 50 viewers, viewers that leave, viewers that stop reading.

    python -m benchmarks.streaming_share [--viewers 50] [--seconds 30] [--only share,stalled]

Against one service this script starts on loopback (``python -m app serve``, the demo rig; stopped whatever
happens), views of the demo recording at 320x240 with 48 planes, closed-loop viewers (each sends its next
viewpoint when its frame came back):
- share: ``--viewers`` viewers start at once: the time to each one's first frame (p50, max) and the frames each got
  in ``--seconds`` (min / median / max: the fair share); a viewer that joins the running crowd half-way: its first
  frame's wait and how many views the session drew meanwhile; then half the viewers leave with a view pending:
  what the session drew for them after they left (its ``turns`` counters).
- stalled: one viewer alone, then beside 5 readers that ask for views and never read a byte (raw sockets): its
  fps, and when the server cut each stalled reader off (``SWEEPCAST_VIEWER_STALL_SECONDS``, default 10).
"""
from __future__ import annotations

import asyncio
import contextlib
import json
import os
import socket
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import httpx
import websockets

from benchmarks._report import Sections, md_table
from harness.servers import CHECKOUT_KERNEL_CACHE, exit_on_sigterm, serve_app, stalled_websocket
from workers.streaming.framing import unpack_message

SIZE = (320, 240)
PLANES = 48
STALLED = 5
STALL_SECONDS = 10.0


def view_message(i: int, phase: float) -> dict:
    """Viewpoint ``i`` of a viewer at ``phase`` degrees: a new pose on the rig's arc every time."""
    return {"id": i, "orbit": {"azimuth": -40.0 + (phase + 1.5 * i) % 80.0}, "width": SIZE[0], "height": SIZE[1],
            "planes": PLANES, "method": "kojima", "frame": 0, "quality": 80}


class Service:
    """The service with the demo recording, started on first use and stopped at the end of the run."""

    def __init__(self) -> None:
        self.stack = contextlib.ExitStack()
        self.base: str | None = None
        self.url = ""
        self.rig_id = ""

    def start(self) -> "Service":
        if self.base is not None:
            return self
        tmp = Path(self.stack.enter_context(tempfile.TemporaryDirectory(prefix="sweepcast-bench-")))
        env = {"SWEEPCAST_DATA_DIR": str(tmp / "data"), "SWEEPCAST_NUMBA_CACHE_DIR": str(CHECKOUT_KERNEL_CACHE),
               "SWEEPCAST_VIEWER_STALL_SECONDS": str(STALL_SECONDS)}
        app = self.stack.enter_context(serve_app(env, log=tmp / "server.log"))
        with httpx.Client(base_url=app.base, timeout=30) as http:
            deadline = time.monotonic() + 900
            while time.monotonic() < deadline:
                rigs = [r for r in http.get("/v1/rigs").json()["rigs"] if r["demo"]]
                recs = http.get(f"/v1/rigs/{rigs[0]['id']}").json()["recordings"] if rigs else []
                if recs and recs[0]["state"] == "ready":
                    break
                if recs and recs[0]["state"] == "failed":
                    raise SystemExit(f"the demo recording failed: {recs[0]['error']}")
                time.sleep(1.0)
            else:
                raise SystemExit(f"no demo recording after 15 min; server log: {app.log_tail()}")
        self.base, self.rig_id = app.base, rigs[0]["id"]
        self.url = f"{app.base.replace('http', 'ws', 1)}/v1/rigs/{self.rig_id}/view?source={recs[0]['id']}"
        asyncio.run(self._warm())
        return self

    async def _warm(self) -> None:
        """One viewer's few frames: the session is made and its kernels loaded before anything is timed."""
        async with websockets.connect(self.url, max_size=None) as ws:
            await _ready(ws)
            for i in range(3):
                await _one(ws, i, 0.0)

    def turns(self) -> dict[str, Any]:
        sessions = httpx.get(f"{self.base}/v1/sessions", timeout=30).json()["sessions"]
        info = next(s["info"] for s in sessions if s["rig_id"] == self.rig_id and s["source"] != "live")
        return {**info["turns"], "renders": info["renders"]}


SERVICE = Service()


async def _ready(ws: Any) -> None:
    while json.loads(await ws.recv())["type"] != "ready":
        pass


async def _one(ws: Any, i: int, phase: float) -> dict:
    """Send viewpoint ``i``; the header of its frame."""
    await ws.send(json.dumps(view_message(i, phase)))
    while True:
        message = await ws.recv()
        if isinstance(message, bytes):
            header, _ = unpack_message(message)
            if header["id"] == i:
                return header
        elif json.loads(message).get("type") == "error":
            raise RuntimeError(message)


# --- share ---------------------------------------------------------------------------------------
async def crowd(url: str, n: int, seconds: float) -> dict[str, Any]:
    """``n`` viewers start at once and run ``seconds``; one more joins half-way; then half of them leave with a
    view pending."""
    sockets = [await websockets.connect(url, max_size=None) for _ in range(n)]
    for ws in sockets:
        await _ready(ws)
    t0 = time.perf_counter()
    end = t0 + seconds
    first: list[float] = [float("nan")] * n
    frames = [0] * n
    last_turn = [0]

    async def run(k: int) -> None:
        i = 0
        while time.perf_counter() < end:
            header = await _one(sockets[k], i, 80.0 * k / n)
            if time.perf_counter() > end:
                return
            if i == 0:
                first[k] = time.perf_counter() - t0
            frames[k] += 1
            last_turn[0] = max(last_turn[0], header["turn"])
            i += 1

    async def joiner() -> dict[str, Any]:
        await asyncio.sleep(seconds / 2)
        async with websockets.connect(url, max_size=None) as ws:
            await _ready(ws)
            seen = last_turn[0]
            t = time.perf_counter()
            header = await _one(ws, 0, 40.0)
            return {"first_frame_s": time.perf_counter() - t, "turns_before_it": header["turn"] - seen - 1,
                    "others": n}

    *_, joined = await asyncio.gather(*(run(k) for k in range(n)), joiner())
    leavers = sockets[: n // 2]
    for k, ws in enumerate(leavers):  # a view pending, then gone
        await ws.send(json.dumps(view_message(10_000 + k, 0.0)))
    for ws in leavers:
        ws.transport.abort()  # gone without a word, as a closed tab or a dropped connection
    for ws in sockets[n // 2:]:
        await ws.close()
    return {"first": first, "frames": frames, "joiner": joined, "leavers": len(leavers)}


def bench_share(args: Any) -> tuple[dict[str, Any], str]:
    service = SERVICE.start()
    before = service.turns()
    r = asyncio.run(crowd(service.url, args.viewers, args.seconds))
    time.sleep(3.0)  # the leavers' sockets are noticed and their views dropped or finished
    after = service.turns()
    first = sorted(r["first"])
    frames = r["frames"]
    out = {
        "viewers": args.viewers, "seconds": args.seconds, "size": f"{SIZE[0]}x{SIZE[1]}", "planes": PLANES,
        "first_frame_s": {"p50": statistics.median(first), "max": max(first)},
        "frames_each": {"min": min(frames), "median": statistics.median(frames), "max": max(frames),
                        "total": sum(frames)},
        "fps_session": sum(frames) / args.seconds,
        "joiner": r["joiner"],
        "gone": {"leavers": r["leavers"],
                 **{k: after[k] - before[k] for k in ("dropped_for_gone", "drawn_for_gone", "superseded")}},
    }
    j, g, f = out["joiner"], out["gone"], out["frames_each"]
    md = (f"### share: {args.viewers} viewers of the demo recording at {out['size']}, {PLANES} planes, "
          f"{args.seconds:g} s\n\n"
          + md_table(["first frame p50 (s)", "first frame max (s)", "frames each min", "median", "max",
                      "session fps (all viewers)", "joiner's first frame (s)", "views drawn before it"],
                     [[out["first_frame_s"]["p50"], out["first_frame_s"]["max"], f["min"], f["median"], f["max"],
                       out["fps_session"], j["first_frame_s"], j["turns_before_it"]]])
          + f"\n\nThen {g['leavers']} viewers left with a view pending: {g['dropped_for_gone']} of their views "
            f"dropped undrawn, {g['drawn_for_gone']} finished after they had left (being drawn as they went); none "
            f"is started for a viewer that left.\n")
    return out, md


# --- stalled -------------------------------------------------------------------------------------
def stalled_reader(base: str, path: str) -> socket.socket:
    """A viewer socket that never reads (harness.servers.stalled_websocket), with a timeout for the closing checks."""
    sock = stalled_websocket(base, path)
    sock.settimeout(2.0)
    return sock


def text_frame(text: str) -> bytes:
    payload, mask = text.encode(), os.urandom(4)
    size = bytes([0x80 | len(payload)]) if len(payload) < 126 else bytes([0x80 | 126]) + len(payload).to_bytes(2, "big")
    return b"\x81" + size + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload))


async def healthy(url: str, seconds: float) -> list[float]:
    """One closed-loop viewer for ``seconds``: the times its frames came."""
    times = []
    async with websockets.connect(url, max_size=None) as ws:
        await _ready(ws)
        end, i = time.perf_counter() + seconds, 0
        while time.perf_counter() < end:
            await _one(ws, i, 20.0)
            times.append(time.perf_counter())
            i += 1
    return times


async def stalled_run(service: Service, seconds: float) -> dict[str, Any]:
    path = urlsplit(service.url)
    readers = [stalled_reader(service.base, f"{path.path}?{path.query}") for _ in range(STALLED)]
    t0 = time.perf_counter()
    cut: list[float | None] = [None] * STALLED

    async def ask() -> None:  # each asks for a view every 50 ms and never reads
        i = 0
        while time.perf_counter() - t0 < seconds and None in cut:
            for k, sock in enumerate(readers):
                if cut[k] is None:
                    try:
                        sock.sendall(text_frame(json.dumps(view_message(i, 10.0 * k))))
                    except TimeoutError:  # the server reads every viewpoint: not expected
                        pass
                    except OSError:
                        cut[k] = time.perf_counter() - t0
            i += 1
            await asyncio.sleep(0.05)

    times, _ = await asyncio.gather(healthy(service.url, seconds), ask())
    for sock in readers:
        sock.close()
    return {"times": [t - t0 for t in times], "cut_s": cut}


def fps(times: list[float], start: float, end: float) -> float:
    return sum(start <= t < end for t in times) / (end - start)


def bench_stalled(args: Any) -> tuple[dict[str, Any], str]:
    service = SERVICE.start()
    alone = asyncio.run(healthy(service.url, args.stalled_seconds))
    alone_fps = (len(alone) - 1) / (alone[-1] - alone[0])
    r = asyncio.run(stalled_run(service, args.stalled_seconds))
    cuts = [c for c in r["cut_s"] if c is not None]
    beside_end = max(cuts) if len(cuts) == STALLED else args.stalled_seconds
    out = {"seconds": args.stalled_seconds, "stall_seconds": STALL_SECONDS, "fps_alone": alone_fps,
           "fps_beside_stalled": fps(r["times"], 0.0, beside_end),
           "fps_after_cut": fps(r["times"], beside_end, args.stalled_seconds) if beside_end < args.stalled_seconds - 1
           else None, "cut_s": r["cut_s"]}
    md = (f"### stalled: one viewer beside {STALLED} readers that never read (stall limit {STALL_SECONDS:g} s)\n\n"
          + md_table(["viewer fps alone", f"fps beside {STALLED} stalled readers", "fps after they were cut off",
                      "stalled readers cut off after (s)"],
                     [[out["fps_alone"], out["fps_beside_stalled"],
                       "-" if out["fps_after_cut"] is None else out["fps_after_cut"],
                       ", ".join("never" if c is None else f"{c:.1f}" for c in r["cut_s"])]]) + "\n")
    return out, md


sections = Sections("streaming_share", __doc__)
sections.parser.add_argument("--viewers", type=int, default=50, help="share: viewers (default 50)")
sections.parser.add_argument("--seconds", type=float, default=30.0, help="share: seconds they run (default 30)")
sections.parser.add_argument("--stalled-seconds", type=float, default=25.0,
                             help="stalled: seconds of each window (default 25)")
sections.add("share", "N viewers at once: first frames, frames each, a joiner, leavers", bench_share)
sections.add("stalled", "a viewer's fps alone and beside readers that stopped reading", bench_stalled)


def markdown(results: dict, kept: list[str]) -> str:
    return "\n".join(sections.stored_markdown(results, kept))


def main(argv: list[str] | None = None) -> int:
    with exit_on_sigterm(), SERVICE.stack:
        return sections.main(markdown, argv)


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
