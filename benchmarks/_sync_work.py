"""The synchronous-work section of benchmarks/robustness.py (``--only sync_work``): what a 49 MP ``wmf`` depth request
costs the API process with the bound of issue 35 off (the limits raised out of reach: the service as it was) and
on (the default settings), and how quickly ``/healthz`` answers another client while three such requests run.

The request is the issue's case, built from Middlebury Art: a 3500x3500 8-bit depth map (disp1, nearest) upsampled
x2 onto its 7000x7000 texture (view1, cubic; JPEG 90 so that the body stays under the upload limit), method wmf.
A 4K request (1920x1080 depth x2 onto a 3840x2160 texture) shows that a valid request within the bound is still
answered, with the same bytes from both servers, alone and three at once (within the memory budget: all run); the
49 MP request sent where the 413 says (a one-frame raw YUV sequence to the job route) shows that the way out works,
on a Ray worker. Per server: the API process's CPU time (utime + stime) and peak
resident memory (VmHWM, reset through /proc/PID/clear_refs before each case) over each case.
"""
from __future__ import annotations

import hashlib
import json
import os
import statistics
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import cv2
import httpx

from harness.proc import cpu_seconds, status_mb
from benchmarks._report import md_table
from harness.servers import ServedApp, serve_app
from workers.common.datasets import dataset
from workers.depth.encoded import filter_work
from workers.depth.params import DepthFilterParams

UNBOUNDED = {"SWEEPCAST_SYNC_MAX_CPU_SECONDS": "1e9", "SWEEPCAST_SYNC_MAX_MEMORY_MB": "1e9",
             "SWEEPCAST_SYNC_MEMORY_BUDGET_MB": "1e9"}
BOUNDED = {name: None for name in UNBOUNDED}  # the defaults
WMF = '{"method": "wmf", "scale": 2}'
CONCURRENT = 3


def art_request(width: int, height: int) -> dict[str, tuple[str, bytes, str]]:
    """Depth (width/2 x height/2, PNG) and texture (width x height, JPEG 90) of Middlebury Art."""
    art = dataset("multiview", "art")
    if art is None:
        raise SystemExit("the sync-work section needs Middlebury Art: $SWEEPCAST_DATA/multiview/art")
    texture = cv2.resize(cv2.imread(str(art / "view1.png")), (width, height), interpolation=cv2.INTER_CUBIC)
    disparity = cv2.imread(str(art / "disp1.png"), cv2.IMREAD_GRAYSCALE)
    depth = cv2.resize(disparity, (width // 2, height // 2), interpolation=cv2.INTER_NEAREST)
    return {"depth": ("depth.png", cv2.imencode(".png", depth)[1].tobytes(), "image/png"),
            "texture": ("texture.jpg", cv2.imencode(".jpg", texture, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes(),
                        "image/jpeg")}


def _answer(r: httpx.Response) -> dict[str, Any]:
    body = r.json() if r.headers.get("content-type", "").startswith("application/json") else None
    return {"status": r.status_code, "error": body.get("error") if body else None,
            "detail": body.get("detail") if body else None, "retry_after": r.headers.get("retry-after"),
            "sha256": hashlib.sha256(r.content).hexdigest() if r.status_code == 200 else None}


def measured(app: ServedApp, requests: list[dict], healthz: bool) -> dict[str, Any]:
    """Send ``requests`` (files dicts) at once to /v1/depth/filter; the answers, wall time, the API process's CPU
    and peak RSS over them, and with ``healthz`` the latencies of /healthz polled every 50 ms meanwhile."""
    pid = app.proc.pid
    if app.proc.poll() is not None:
        raise RuntimeError(f"the API exited before this case: {app.log_tail()}")
    Path(f"/proc/{pid}/clear_refs").write_text("5")  # VmHWM := VmRSS
    rss_before, cpu_before, load_before = status_mb(pid, "VmRSS"), cpu_seconds(pid), os.getloadavg()[0]
    answers: list[dict] = [{}] * len(requests)
    latencies: list[float] = []
    failures: list[float] = []

    def send(i: int, files: dict) -> None:
        with httpx.Client(base_url=app.base, timeout=600) as c:
            try:
                answers[i] = _answer(c.post("/v1/depth/filter", files=files, data={"params": WMF}))
            except httpx.TransportError as exc:  # the API died or dropped the connection: that is the answer
                answers[i] = {"status": "no answer", "error": type(exc).__name__, "detail": str(exc),
                              "retry_after": None, "sha256": None}

    threads = [threading.Thread(target=send, args=(i, files)) for i, files in enumerate(requests)]
    t0 = time.perf_counter()
    for t in threads:
        t.start()
    with httpx.Client(base_url=app.base, timeout=120) as probe:
        while healthz and any(t.is_alive() for t in threads):
            s = time.perf_counter()
            try:
                ok = probe.get("/healthz").status_code == 200
            except httpx.TransportError:
                ok = False
            latencies.append(time.perf_counter() - s) if ok else failures.append(time.perf_counter() - s)
            time.sleep(0.05)
    for t in threads:
        t.join()
    out = {"answers": answers, "seconds": time.perf_counter() - t0, "api_cpu_seconds": cpu_seconds(pid) - cpu_before,
           "api_rss_before_mb": rss_before, "api_peak_rss_mb": status_mb(pid, "VmHWM"),
           "load_average": [load_before, os.getloadavg()[0]]}
    if healthz:
        ms = sorted(x * 1000 for x in latencies) or [float("nan")]
        out["healthz_ms"] = {"count": len(latencies), "failed": len(failures), "p50": statistics.median(ms),
                             "p95": ms[int(0.95 * (len(ms) - 1))], "max": ms[-1]}
    out["api_alive_after"] = app.proc.poll() is None
    return out


def yuv_job_files(width: int, height: int) -> dict[str, tuple[str, bytes, str]]:
    """The same Art request as the job route takes it: one raw 8-bit 4:0:0 depth frame and one 4:2:0 texture frame."""
    art = dataset("multiview", "art")
    texture = cv2.resize(cv2.imread(str(art / "view1.png")), (width, height), interpolation=cv2.INTER_CUBIC)
    disparity = cv2.imread(str(art / "disp1.png"), cv2.IMREAD_GRAYSCALE)
    depth = cv2.resize(disparity, (width // 2, height // 2), interpolation=cv2.INTER_NEAREST)
    return {"depth": ("depth.yuv", depth.tobytes(), "application/octet-stream"),
            "texture": ("texture.yuv", cv2.cvtColor(texture, cv2.COLOR_BGR2YUV_I420).tobytes(),
                        "application/octet-stream")}


def as_job(app: ServedApp, files: dict, width: int, height: int) -> dict[str, Any]:
    """The 49 MP request sent where the 413 says: a one-frame sequence to POST /v1/depth/videos, run by a Ray
    worker; the job's outcome and what the API process spent meanwhile."""
    pid = app.proc.pid
    Path(f"/proc/{pid}/clear_refs").write_text("5")
    rss_before, cpu_before, load_before = status_mb(pid, "VmRSS"), cpu_seconds(pid), os.getloadavg()[0]
    params = {"width": width // 2, "height": height // 2, "method": "wmf", "scale": 2}
    t0 = time.perf_counter()
    with httpx.Client(base_url=app.base, timeout=600) as c:
        r = c.post("/v1/depth/videos", files=files, data={"params": json.dumps(params)})
        job = r.json()
        while r.status_code == 202 and job["state"] not in ("succeeded", "failed", "cancelled"):
            time.sleep(0.5)
            job = c.get(f"/v1/jobs/{job['id']}").json()
        size = (len(c.get(f"/v1/jobs/{job['id']}/results/filtered.yuv").content)
                if job.get("state") == "succeeded" else None)
    return {"status": r.status_code, "state": job.get("state"), "error": job.get("error"), "output_bytes": size,
            "seconds": time.perf_counter() - t0, "api_cpu_seconds": cpu_seconds(pid) - cpu_before,
            "api_rss_before_mb": rss_before, "api_peak_rss_mb": status_mb(pid, "VmHWM"),
            "load_average": [load_before, os.getloadavg()[0]], "params": params}


def one_server(env: dict[str, str | None], big: dict, small: dict, job: dict | None = None) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="sc-syncwork-") as data_dir, \
            serve_app({"SWEEPCAST_DATA_DIR": data_dir, "SWEEPCAST_DEMO_RIG": "false", **env},
                      log=Path(data_dir) / "api.log") as app:
        warm = art_request(64, 64)  # loads the wmf kernel in the API process
        with httpx.Client(base_url=app.base, timeout=120) as c:
            c.post("/v1/depth/filter", files=warm, data={"params": WMF}).raise_for_status()
        result = {"within_bound_4k": measured(app, [small], healthz=False),
                  "three_4k": measured(app, [small] * CONCURRENT, healthz=True),
                  "one_49mp": measured(app, [big], healthz=False),
                  "three_49mp": measured(app, [big] * CONCURRENT, healthz=True)}
        if job is not None:
            result["as_job"] = as_job(app, job, 7000, 7000)
    return result


def estimate(files: dict) -> dict[str, float]:
    """The route's own estimate of a request (:func:`workers.depth.encoded.filter_work`)."""
    est, _ = filter_work(files["depth"][1], DepthFilterParams.model_validate_json(WMF), files["texture"][1], 10**9)
    return {"cpu_seconds": est.cpu_seconds, "peak_mb": est.peak_bytes / 2**20}


def sync_work() -> dict[str, Any]:
    big, small = art_request(7000, 7000), art_request(3840, 2160)
    return {"request": {"depth": "3500x3500 8-bit PNG", "texture": "7000x7000 JPEG 90", "params": WMF,
                        "depth_bytes": len(big["depth"][1]), "texture_bytes": len(big["texture"][1])},
            "estimates": {"within_bound_4k": estimate(small), "one_49mp": estimate(big)},
            "unbounded": one_server(UNBOUNDED, big, small),
            "bounded": one_server(BOUNDED, big, small, yuv_job_files(7000, 7000))}


def _status(m: dict) -> str:
    """The answers of one case, counted: "3x 413 too_much_work"."""
    labels = [f"{a['status']} {a['error'] or ''}".strip() for a in m["answers"]]
    if not m["api_alive_after"]:
        labels.append("API process gone")
    return ", ".join(f"{labels.count(k)}x {k}" for k in sorted(set(labels)))


def markdown(r: dict[str, Any]) -> str:
    rows = []
    for server, label in (("unbounded", "bound off (limits out of reach: as before issue 35)"),
                          ("bounded", "bound on (default settings)")):
        for case, what in (("within_bound_4k", "one 4K wmf (3840x2160)"),
                           ("three_4k", f"{CONCURRENT} x 4K wmf at once"), ("one_49mp", "one 49 MP wmf"),
                           ("three_49mp", f"{CONCURRENT} x 49 MP wmf at once")):
            m = r[server][case]
            h = m.get("healthz_ms")
            rows.append([label, what, _status(m), round(m["seconds"], 2), round(m["api_cpu_seconds"], 1),
                         round(m["api_rss_before_mb"]), round(m["api_peak_rss_mb"]),
                         f"{h['p50']:.0f} / {h['p95']:.0f} / {h['max']:.0f} ({h['count']} ok, {h['failed']} failed)"
                         if h else "",
                         " -> ".join(f"{x:.2f}" for x in m["load_average"])])
    j = r["bounded"]["as_job"]
    rows.append(["bound on (default settings)", "one 49 MP wmf as a job (POST /v1/depth/videos, one raw YUV frame)",
                 f"{j['status']}, job {j['state']}" + (f" ({j['output_bytes']:,} bytes out)" if j["output_bytes"] else
                                                       f": {j['error']}"),
                 round(j["seconds"], 2), round(j["api_cpu_seconds"], 1), round(j["api_rss_before_mb"]),
                 round(j["api_peak_rss_mb"]), "", " -> ".join(f"{x:.2f}" for x in j["load_average"])])
    same = len({r[s]["within_bound_4k"]["answers"][0]["sha256"] for s in ("unbounded", "bounded")}) == 1
    refused = next((a["detail"] for a in r["bounded"]["one_49mp"]["answers"] if a["detail"]), "")
    req = r["request"]
    est_rows = [[what, round(r["estimates"][case]["cpu_seconds"], 1), round(r["unbounded"][case]["api_cpu_seconds"], 1),
                 round(r["estimates"][case]["peak_mb"]),
                 round(r["unbounded"][case]["api_peak_rss_mb"] - r["unbounded"][case]["api_rss_before_mb"])]
                for case, what in (("within_bound_4k", "4K wmf"), ("one_49mp", "49 MP wmf"))]
    return (
        f"The issue-35 case, `POST /v1/depth/filter` with params `{req['params']}`: a {req['depth']} depth map "
        f"({req['depth_bytes']:,} bytes) and a {req['texture']} texture ({req['texture_bytes']:,} bytes) from "
        f"Middlebury Art. CPU and peak RSS are the API process's over each case (VmHWM reset before it); "
        f"`/healthz` was polled every 50 ms by another client while the {CONCURRENT} requests ran. Timing figures "
        f"were taken on a shared machine: the load average (1 min) before and after each case is beside them.\n\n"
        + md_table(["server", "case", "answers", "wall s", "API CPU s", "API RSS before MB", "API peak RSS MB",
                    "/healthz p50 / p95 / max ms (n)", "load average"], rows)
        + f"\n\nThe 4K answer is the same bytes from both servers: **{'yes' if same else 'NO'}**. "
          f"The 413's detail: \"{refused}\"\n\n"
        "The route's estimate (workers/depth/cost.py) against the measured cost (bound off, one request alone):\n\n"
        + md_table(["request", "estimated CPU s", "measured API CPU s", "estimated peak MB",
                    "measured API peak RSS growth MB"], est_rows)
    )
