"""Robustness: what hostile input, load and lost processes do to the service.

    python -m benchmarks.robustness [--only service,tenants,sync_work] [--quick]

Three parts, each its own results section (robustness, robustness_tenants, robustness_sync_work); without --only
all three run. The part ``service`` (each against servers this script starts on loopback and stops, whatever
happens):
- kernel stress: the compiled depth searches on random rigs with misaligned arrays at 1, 2 and 4 threads
  (:mod:`harness.kernel_stress`), each run in a subprocess; a crash is a run that ended with a signal.
- abuse cases: every hostile request of the reliability issue replayed; each must answer 4xx with the JSON
  error body (or a WebSocket error / close code), quickly, with the API's memory bounded.
- fuzzing: schemathesis over the whole OpenAPI document (fixed seed, every check), cases and server errors.
- load: concurrent clients posting real photos to ``/v1/photos/orientation`` for a fixed time.
- kill cycles: photo batches in flight while a Ray worker and then the API itself are killed with SIGKILL
  and the API restarted on the same data; every job must end ``succeeded`` (none lost, none failed).
The API's peak RSS (VmHWM of its process) is read after each section.
The part ``tenants`` (robustness_tenants, from :mod:`benchmarks._tenants`): cross-key probes over every resource
operation and socket, quota probes, and the cost of the owner filter and of the key lookup; the script exits 1 when a
probe saw another key's resource.
The part ``sync_work`` (robustness_sync_work, from :mod:`benchmarks._sync_work`): a 49 MP wmf depth request's cost to
the API process with the bound off and on, and ``/healthz`` latency while three run; the script exits 1 when the
bound did not hold.
"""
from __future__ import annotations

import argparse
import asyncio
import io
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import cv2
import httpx
import numpy as np
import piexif
from websockets.sync.client import connect

from harness.proc import status_mb
from benchmarks import _sync_work, _tenants
from benchmarks._report import Sections, md_table
from harness.servers import ServedApp, serve_app
from workers.common.datasets import data_root, dataset

ROOT = Path(__file__).resolve().parents[1]

MiB = 2**20
SYNTH_PARAMS = {"depth_units": "disparity", "positions": [0, 2], "target_position": 1}


# ---------------------------------------------------------------- kernel stress

def kernel_stress(reps: int) -> dict:
    out = {}
    for threads in (1, 2, 4):
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "harness.kernel_stress", "--reps", str(reps), "--threads",
                               str(threads), "--seed", str(1000 + threads)], cwd=ROOT, capture_output=True, text=True,
                              env={**os.environ, "NUMBA_NUM_THREADS": "4"})
        report = json.loads(proc.stdout.strip().splitlines()[-1]) if proc.returncode >= 0 and proc.stdout else {}
        out[f"threads_{threads}"] = {
            "reps": reps, "crashed": proc.returncode < 0,
            "signal": signal.Signals(-proc.returncode).name if proc.returncode < 0 else None,
            "wrong": proc.returncode > 0, "worst_disagreement": report.get("worst_disagreement"),
            "pixels_with_depth": report.get("pixels_with_depth"), "seconds": time.perf_counter() - t0}
        print(f"  kernel stress, {threads} threads: rc {proc.returncode}", flush=True)
    return out


# ---------------------------------------------------------------- abuse cases

def png(img: np.ndarray) -> bytes:
    return cv2.imencode(".png", img)[1].tobytes()


def jpeg_declaring(width: int, height: int) -> bytes:
    """A small valid JPEG whose SOF header is rewritten to claim width x height pixels."""
    data = bytearray(cv2.imencode(".jpg", np.full((16, 16, 3), 128, np.uint8))[1].tobytes())
    i = 2
    while i < len(data):
        marker, length = data[i + 1], int.from_bytes(data[i + 2:i + 4], "big")
        if marker in (0xC0, 0xC1, 0xC2):
            data[i + 5:i + 7] = height.to_bytes(2, "big")
            data[i + 7:i + 9] = width.to_bytes(2, "big")
            return bytes(data)
        i += 2 + length
    raise AssertionError("no SOF marker")


def zip_bomb(member_bytes: int) -> bytes:
    """A zip holding one member of ``member_bytes`` zeros (deflated ~1000:1)."""
    buf = io.BytesIO()
    chunk = b"\0" * MiB
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z, z.open("frames/0001.png", "w", force_zip64=True) as f:
        for _ in range(member_bytes // MiB):
            f.write(chunk)
    return buf.getvalue()


def jpeg_with_orientation(value: int) -> bytes:
    img = np.full((64, 48, 3), 180, np.uint8)
    cv2.circle(img, (24, 30), 12, (40, 40, 40), -1)
    out = io.BytesIO()
    piexif.insert(piexif.dump({"0th": {piexif.ImageIFD.Orientation: value}}), cv2.imencode(".jpg", img)[1].tobytes(),
                  out)
    return out.getvalue()


def raw_request_until_answer(host: str, port: int, head: bytes, first_body: bytes, timeout: float = 10.0
                             ) -> tuple[int | None, float, int]:
    """Send ``head`` and the first part of a body that its Content-Length says is much larger, then wait for
    an answer without sending more: (status or None, seconds to the answer, body bytes sent)."""
    t0 = time.perf_counter()
    with socket.create_connection((host, port), timeout=timeout) as s:
        s.sendall(head + first_body)
        try:
            line = s.recv(4096).split(b"\r\n", 1)[0]
        except OSError:
            return None, time.perf_counter() - t0, len(first_body)
    status = int(line.split()[1]) if line.startswith(b"HTTP/") else None
    return status, time.perf_counter() - t0, len(first_body)


def answer(r: httpx.Response, t0: float) -> dict:
    try:
        body = r.json()
    except ValueError:
        body = None
    ok = 400 <= r.status_code < 500 and isinstance(body, dict) and "error" in body and "detail" in body
    return {"status": r.status_code, "error": body.get("error") if isinstance(body, dict) else None,
            "detail": str(body.get("detail"))[:160] if isinstance(body, dict) else r.text[:160],
            "seconds": time.perf_counter() - t0, "ok": ok}


def http_cases(app: ServedApp, rig_id: str | None) -> dict:
    c = httpx.Client(base_url=app.base, timeout=120)
    tiny = png(np.full((8, 8), 100, np.uint8))
    tex = png(np.full((8, 8, 3), 100, np.uint8))
    bomb = png(np.zeros((7900, 7900), np.uint8))
    sof = jpeg_declaring(65000, 65000)
    cases = {
        "depth_filter_empty_image": lambda: c.post("/v1/depth/filter", files={
            "depth": ("d.png", b"", "image/png"), "texture": ("t.png", tex, "image/png")}),
        "depth_synthesize_empty_image": lambda: c.post("/v1/depth/synthesize", files=[
            ("depths", ("a.png", b"", "image/png")), ("depths", ("b.png", tiny, "image/png")),
            ("textures", ("a.png", tex, "image/png")), ("textures", ("b.png", b"", "image/png"))],
            data={"params": json.dumps(SYNTH_PARAMS)}),
        "depth_filter_jpeg_sof_65000x65000": lambda: c.post("/v1/depth/filter", files={
            "depth": ("d.jpg", sof, "image/jpeg"), "texture": ("t.jpg", sof, "image/jpeg")}),
        "orientation_jpeg_sof_65000x65000": lambda: c.post("/v1/photos/orientation", files={
            "file": ("p.jpg", sof, "image/jpeg")}),
        "depth_filter_png_bomb_7900x7900": lambda: c.post("/v1/depth/filter", files={
            "depth": ("d.png", bomb, "image/png"), "texture": ("t.png", tex, "image/png")}),
        "depth_filter_output_16384x16384": lambda: c.post("/v1/depth/filter", files={
            "depth": ("d.png", tiny, "image/png"), "texture": ("t.png", tex, "image/png")},
            data={"params": json.dumps({"out_width": 16384, "out_height": 16384})}),
        "depth_filter_output_32768x32768": lambda: c.post("/v1/depth/filter", files={
            "depth": ("d.png", tiny, "image/png"), "texture": ("t.png", tex, "image/png")},
            data={"params": json.dumps({"out_width": 32768, "out_height": 32768})}),
        "jobs_offset_2_63": lambda: c.get("/v1/jobs", params={"offset": str(2**63)}),
        "jobs_limit_negative": lambda: c.get("/v1/jobs", params={"limit": "-1"}),
        "rig_fx_infinity": lambda: c.post("/v1/rigs", files={"files": ("rig.json", json.dumps({"cameras": [
            {"name": f"c{i}", "width": 64, "height": 48, "K": [["Infinity", 0, 32], [0, 50, 24], [0, 0, 1]],
             "R": np.eye(3).tolist(), "t": [i * 0.1, 0, 0]} for i in range(2)]}).replace('"Infinity"', "Infinity"),
            "application/json")}),
        "synthesize_positions_nan": lambda: c.post("/v1/depth/synthesize", files=[
            ("depths", ("a.png", tiny, "image/png")), ("depths", ("b.png", tiny, "image/png")),
            ("textures", ("a.png", tex, "image/png")), ("textures", ("b.png", tex, "image/png"))],
            data={"params": json.dumps(SYNTH_PARAMS).replace("[0, 2]", "[NaN, 2]")}),
        "params_nested_json": lambda: c.post("/v1/depth/filter", files={
            "depth": ("d.png", tiny, "image/png"), "texture": ("t.png", tex, "image/png")},
            data={"params": "[" * 100000 + "]" * 100000}),
        "drone_zip_bomb_2gib_member": lambda: c.post("/v1/reconstructions", files={
            "media": ("stills.zip", zip_bomb(2048 * MiB), "application/zip")},
            data={"params": json.dumps({"fx": 500, "fy": 500, "cx": 160, "cy": 120})}),
    }
    if rig_id is not None:
        cases["renders_json_body_64mib"] = lambda: c.post(
            f"/v1/rigs/{rig_id}/renders", content=b'{"width": 64, "height": 48, "pad": "' + b"x" * (64 * MiB) + b'"}',
            headers={"content-type": "application/json"})
    out = {}
    for name, call in cases.items():
        t0 = time.perf_counter()
        try:
            out[name] = answer(call(), t0)
        except httpx.HTTPError as exc:
            out[name] = {"status": None, "error": type(exc).__name__, "detail": str(exc)[:160],
                         "seconds": time.perf_counter() - t0, "ok": False}
        print(f"  {name}: {out[name]['status']}", flush=True)
    out["drone_zip_bomb_2gib_member"].update(zip_job_outcome(c, out["drone_zip_bomb_2gib_member"]))
    out["orient_stored_orientation_99"] = orientation_99(c)
    return out


def zip_job_outcome(c: httpx.Client, first: dict) -> dict:
    """A zip accepted for a job must fail that job with the reason (not run it, not kill a worker)."""
    if first["status"] != 202:
        return {}
    job_id = c.get("/v1/jobs").json()["jobs"][0]["id"]
    deadline = time.monotonic() + 300
    job = {}
    while time.monotonic() < deadline:
        job = c.get(f"/v1/jobs/{job_id}").json()
        if job["state"] in ("succeeded", "failed", "cancelled"):
            break
        time.sleep(0.5)
    failed_with_reason = job.get("state") == "failed" and "internal error" not in (job.get("error") or "")
    return {"job_state": job.get("state"), "job_error": (job.get("error") or "")[:200], "ok": failed_with_reason}


def orientation_99(c: httpx.Client) -> dict:
    t0 = time.perf_counter()
    r = c.post("/v1/photos/orient", files={"file": ("p.jpg", jpeg_with_orientation(99), "image/jpeg")})
    header = r.headers.get("x-orientation")
    return {"status": r.status_code, "x_orientation": header, "seconds": time.perf_counter() - t0,
            "ok": r.status_code < 500 and header in (None, "none", *map(str, range(1, 9)))}


def demo_rig_ready(c: httpx.Client, timeout: float = 240) -> str | None:
    """The demo rig's id once its recording is ready (built at start-up), None if it never is."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        rigs = c.get("/v1/rigs").json().get("rigs", [])
        if rigs:
            recordings = c.get(f"/v1/rigs/{rigs[0]['id']}").json().get("recordings", [])
            if recordings and recordings[0]["state"] == "ready":
                return rigs[0]["id"]
        time.sleep(1.0)
    return None


def socket_cases(app: ServedApp, rig_id: str | None) -> dict:
    """Deeply nested JSON and an oversize message on the viewer socket: an error message or a close with a
    code, never a dropped connection; the socket (or a new one) still renders afterwards."""
    if rig_id is None:
        return {}
    url = app.base.replace("http://", "ws://") + f"/v1/rigs/{rig_id}/view"
    out = {}
    for name, text in (("view_nested_json_200k_chars", "[" * 100000 + "]" * 100000),
                       ("view_nested_json_8k_chars", "[" * 4000 + "]" * 4000), ("view_message_1mib", "x" * MiB)):
        t0 = time.perf_counter()
        result: dict = {"ok": False}
        try:
            with connect(url, open_timeout=30, max_size=None) as ws:
                while not ws.recv(timeout=30).startswith('{"type": "hello"'):
                    pass  # the session greets first
                ws.send(text)
                while isinstance(reply := ws.recv(timeout=30), str) and json.loads(reply).get("type") == "ready":
                    pass  # the session's "ready" may come before the answer
                code = json.loads(reply).get("error") if isinstance(reply, str) else None
                result = {"reply": reply[:200] if isinstance(reply, str) else f"<{len(reply)} bytes>",
                          "error": code, "ok": code is not None}
                ws.send(json.dumps({"id": 1, "width": 96, "height": 72, "planes": 24}))  # the socket still serves
                while isinstance(after := ws.recv(timeout=60), str) and '"error"' not in after:
                    pass  # "ready" and the like; a frame is a binary message
                result["next_view"] = "frame" if isinstance(after, bytes) else after[:160]
                result["ok"] = result["ok"] and result["next_view"] == "frame"
        except Exception as exc:  # a close frame with a code is a fine answer; a dropped connection is not
            code = getattr(getattr(exc, "rcvd", None), "code", None)
            result = {"closed_with": code, "reason": str(exc)[:160], "ok": code is not None and code != 1006}
        result["seconds"] = time.perf_counter() - t0
        out[name] = result
        print(f"  {name}: {result}", flush=True)
    return out


def body_before_auth_case(app: ServedApp) -> dict:
    """On a server with API keys, a request without one that declares a 200 MB body gets its 401 before
    the body is sent."""
    host, port = app.base.removeprefix("http://").split(":")
    boundary = "b0undary"
    head = (f"POST /v1/photos/orientation HTTP/1.1\r\nHost: {host}\r\nContent-Type: multipart/form-data; "
            f"boundary={boundary}\r\nContent-Length: {200 * 10**6}\r\n\r\n").encode()
    status, seconds, sent = raw_request_until_answer(host, int(port), head, b"--" + boundary.encode() + b"\r\n" +
                                                     b"x" * 65536)
    return {"status": status, "seconds": seconds, "body_bytes_sent": sent, "ok": status == 401 and seconds < 5}


def token_redacted_case(app: ServedApp) -> dict:
    secret = "sekrit-token-4711"
    httpx.get(f"{app.base}/v1/sessions", params={"access_token": secret}, timeout=30)
    time.sleep(0.5)
    leaked = secret in app.log_tail(10**7)
    return {"token_in_access_log": leaked, "ok": not leaked}


# ---------------------------------------------------------------- fuzzing

FUZZ_CONFIG = ROOT / "tests" / "app" / "contract_fuzz.toml"
FUZZ_SERVER_ENV = {  # as the contract test's service: a key, and jobs accepted but never run (see that test)
    "SWEEPCAST_DEMO_RIG": "false", "SWEEPCAST_JOB_RESOURCES": '{"contract_fuzz_no_worker": 1}',
    "SWEEPCAST_JOB_UNSCHEDULABLE_SECONDS": "0.5"}


def fuzz(app: ServedApp, key: str, max_examples: int, seed: int) -> dict:
    """schemathesis over the whole document with the contract test's settings (tests/app/contract_fuzz.toml:
    phases, checks and their reasoned exceptions), more examples and another seed; counts from its report."""
    reports = Path(tempfile.mkdtemp(prefix="sc-fuzz-"))
    args = ["--config-file", str(FUZZ_CONFIG), "--no-color", "run", f"{app.base}/openapi.json", "--seed", str(seed),
            "--max-examples", str(max_examples), "--report", "json", "--report-dir", str(reports)]
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "schemathesis.cli", *args], cwd=reports, capture_output=True,
                          text=True, env={**os.environ, "SWEEPCAST_FUZZ_KEY": key,
                                          "SCHEMATHESIS_HOOKS": str(ROOT / "tests" / "app" / "fuzz_cross_key.py")})
    found = sorted(reports.glob("*.json"))
    report = json.loads(found[-1].read_text()) if found else {}
    failures = {f"{f['code']} {f['title']} ({', '.join(f.get('operations', []))})": f["count"]
                for f in report.get("failures", [])}
    cases = report.get("test_cases", {})
    return {"command": "schemathesis " + " ".join(args[:-4]).replace(str(ROOT) + "/", ""),
            "exit_code": proc.returncode, "cases": cases.get("generated", 0),
            "cases_with_failures": cases.get("with_failures"), "errored": cases.get("errored"),
            "server_errors": sum(n for k, n in failures.items() if "server error" in k.lower()),
            "failures": failures, "operations": report.get("operations"), "seconds": time.perf_counter() - t0,
            "output_tail": proc.stdout[-1500:] if proc.returncode else ""}


# ---------------------------------------------------------------- load

def photo_bytes() -> list[tuple[str, bytes]]:
    folder = dataset("faces", "dev")
    files = sorted(p for p in folder.rglob("*") if p.suffix.lower() in (".jpg", ".jpeg")) if folder else []
    if files:
        return [(p.name, p.read_bytes()) for p in files[:24]]
    from harness.photos import noise_jpeg
    return [(f"p{i}.jpg", noise_jpeg(seed=i)) for i in range(8)]


async def _client(base: str, photos: list, until: float, lat: list, statuses: dict, k: int) -> None:
    async with httpx.AsyncClient(base_url=base, timeout=120) as c:
        i = k
        while time.monotonic() < until:
            name, data = photos[i % len(photos)]
            i += 1
            t0 = time.perf_counter()
            try:
                r = await c.post("/v1/photos/orientation", files={"file": (name, data, "image/jpeg")})
                statuses[r.status_code] = statuses.get(r.status_code, 0) + 1
            except httpx.HTTPError as exc:
                statuses[type(exc).__name__] = statuses.get(type(exc).__name__, 0) + 1
            lat.append(time.perf_counter() - t0)


def load(app: ServedApp, clients: int, seconds: float) -> dict:
    photos = photo_bytes()
    lat: list[float] = []
    statuses: dict = {}
    until = time.monotonic() + seconds

    async def main() -> None:
        await asyncio.gather(*(_client(app.base, photos, until, lat, statuses, k) for k in range(clients)))

    t0 = time.perf_counter()
    asyncio.run(main())
    wall = time.perf_counter() - t0
    lat.sort()
    return {"clients": clients, "seconds": wall, "requests": len(lat), "per_second": len(lat) / wall,
            "p50_ms": 1e3 * lat[len(lat) // 2] if lat else None,
            "p95_ms": 1e3 * lat[int(len(lat) * 0.95)] if lat else None,
            "statuses": {str(k): v for k, v in statuses.items()},
            "server_errors": sum(v for k, v in statuses.items() if isinstance(k, int) and k >= 500),
            "photos": "real (faces/dev)" if dataset("faces", "dev") else "generated"}


# ---------------------------------------------------------------- kill cycles

def batch_files(count: int) -> list:
    photos = photo_bytes()
    return [("files", (f"p{i}.jpg", photos[i % len(photos)][1], "image/jpeg")) for i in range(count)]


def worker_pid(app: ServedApp, job_id: str, timeout: float = 60) -> int | None:
    """The pid of the Ray worker running a job, from its event stream's ``started`` event."""
    url = app.base.replace("http://", "ws://") + f"/v1/jobs/{job_id}/events"
    deadline = time.monotonic() + timeout
    with connect(url, open_timeout=30) as ws:
        while time.monotonic() < deadline:
            event = json.loads(ws.recv(timeout=timeout))
            if event.get("type") == "started":
                return int(event["pid"])
            if event.get("type") in ("succeeded", "failed", "cancelled") or event.get("state") in ("succeeded", "failed"):
                return None
    return None


def kill_cycles(cycles: int, batch: int) -> dict:
    """Per cycle: submit photo batches, SIGKILL the Ray worker of one mid-job, SIGKILL the API, start it again
    on the same data. At the end every job ever submitted must have succeeded."""
    data_dir = tempfile.mkdtemp(prefix="sc-robust-kill-")
    env = {"SWEEPCAST_DATA_DIR": data_dir, "SWEEPCAST_DEMO_RIG": "false", "SWEEPCAST_JOB_LEASE_SECONDS": "5"}
    submitted: list[str] = []
    worker_kills = api_kills = 0
    log = Path(data_dir) / "api.log"
    for cycle in range(cycles):
        with serve_app(env, log=log) as app:
            c = httpx.Client(base_url=app.base, timeout=120)
            ids = [c.post("/v1/photos/batches", files=batch_files(batch)).json()["id"] for _ in range(2)]
            submitted += ids
            pid = worker_pid(app, ids[0])
            if pid is not None:
                os.kill(pid, signal.SIGKILL)
                worker_kills += 1
            time.sleep(1.0)
            os.kill(app.proc.pid, signal.SIGKILL)  # the API dies with jobs queued and running
            app.proc.wait()
            api_kills += 1
        print(f"  kill cycle {cycle + 1}/{cycles}", flush=True)
    with serve_app(env, log=log) as app:
        c = httpx.Client(base_url=app.base, timeout=120)
        final = {}
        deadline = time.monotonic() + 600
        for job_id in submitted:
            while time.monotonic() < deadline:
                r = c.get(f"/v1/jobs/{job_id}")
                job = r.json() if r.status_code == 200 else {"state": "missing"}
                if job["state"] in ("succeeded", "failed", "cancelled", "missing"):
                    break
                time.sleep(0.5)
            final[job_id] = job
    states = [j["state"] for j in final.values()]
    return {"cycles": cycles, "jobs": len(submitted), "worker_kills": worker_kills, "api_kills": api_kills,
            "succeeded": states.count("succeeded"), "lost": states.count("missing") + sum(
                s not in ("succeeded", "failed", "cancelled", "missing") for s in states),
            "falsely_failed": states.count("failed"),
            "worker_losses_counted": sum(j.get("worker_losses", 0) for j in final.values()),
            "service_restarts_counted": sum(j.get("service_restarts", 0) for j in final.values()),
            "errors": sorted({j.get("error") for j in final.values() if j.get("error")})[:5]}


# ---------------------------------------------------------------- report

def outcome(v: dict) -> str:
    """What came back in one abuse case, in a few words."""
    if "reply" in v:
        return f"socket error {v['error']}, then a {v['next_view']}"
    if "token_in_access_log" in v:
        return "token in the access log" if v["token_in_access_log"] else "token redacted in the access log"
    if "body_bytes_sent" in v:
        return f"answered after {v['body_bytes_sent']:,} of 200,000,000 body bytes"
    if "job_state" in v:
        return f"job {v['job_state']}: {v['job_error'][:90]}"
    if "x_orientation" in v:
        return f"X-Orientation: {v['x_orientation']}"
    return v.get("error") or ""


def markdown(r: dict) -> str:
    parts = []
    ks = r["kernel_stress"]
    parts.append("### Kernel stress (random rigs, misaligned arrays, every search variant against the numpy "
                 "definition; one subprocess per thread count)\n\n" + md_table(
                     ["threads", "repetitions", "crashed", "wrong", "worst disagreement", "pixels with depth", "s"],
                     [[k.split("_")[1], v["reps"], v["signal"] or "no", v["wrong"], v["worst_disagreement"],
                       round(v["pixels_with_depth"] or 0, 3), round(v["seconds"], 1)] for k, v in ks.items()]))
    rows = [[name, v.get("status", v.get("closed_with", "")), outcome(v), round(v.get("seconds", 0), 2),
             "yes" if v["ok"] else "**NO**"] for name, v in r["abuse"].items()]
    parts.append("### Abuse cases (each must be a 4xx with the JSON error body, a WebSocket error or close code, "
                 "or a job failed with its reason)\n\n" + md_table(["case", "status", "error / outcome", "s", "ok"],
                                                                    rows))
    f = r["fuzz"]
    parts.append(f"### Fuzzing (schemathesis with the contract test's checks, against a server with an API key)\n\n"
                 f"{f['cases']} cases in {f['seconds']:.0f} s, **{f['server_errors']} server errors**, "
                 f"{f['cases_with_failures']} cases with any failure ({json.dumps(f['failures']) if f['failures'] else 'none'}), "
                 f"{f['errored']} errored. Command: `{f['command']}`")
    ld = r["load"]
    parts.append(f"### Load ({ld['clients']} concurrent clients for {ld['seconds']:.0f} s, `/v1/photos/orientation`, "
                 f"{ld['photos']} photos, detector {ld['detector']})\n\n"
                 + md_table(["requests", "per s", "p50 ms", "p95 ms", "statuses", "5xx"],
                            [[ld["requests"], round(ld["per_second"], 1), round(ld["p50_ms"] or 0),
                              round(ld["p95_ms"] or 0), json.dumps(ld["statuses"]), ld["server_errors"]]]))
    kc = r["kill_cycles"]
    parts.append("### Kill -9 cycles (photo batches in flight; SIGKILL a Ray worker, then the API; restart on the "
                 "same data)\n\n" + md_table(
                     ["cycles", "jobs", "worker kills", "API kills", "succeeded", "lost", "falsely failed",
                      "worker losses counted", "restarts counted"],
                     [[kc["cycles"], kc["jobs"], kc["worker_kills"], kc["api_kills"], kc["succeeded"], kc["lost"],
                       kc["falsely_failed"], kc["worker_losses_counted"], kc["service_restarts_counted"]]]))
    rss = r["api_peak_rss_mb"]
    parts.append(f"API peak RSS (VmHWM of the API process): **{rss['abuse_and_load']:.0f} MB** over the abuse cases "
                 f"and the load, **{rss['fuzz']:.0f} MB** over the fuzzing.")
    return "\n\n".join(parts)


def bench_service(args: argparse.Namespace) -> tuple[dict, str]:
    """The part robustness: kernel stress, abuse cases, fuzzing, load and kill cycles (the module docstring)."""
    q = args.quick
    results: dict = {"kernel_stress": kernel_stress(50 if q else 500)}
    data_dir = tempfile.mkdtemp(prefix="sc-robust-")
    yunet = data_root().parent / "models" / "yunet" / "face_detection_yunet_2023mar.onnx"
    env = {"SWEEPCAST_DATA_DIR": data_dir, "SWEEPCAST_ORIENTATION_YUNET_MODEL": str(yunet) if yunet.is_file() else None}
    with serve_app(env, log=Path(data_dir) / "api.log") as app:
        c = httpx.Client(base_url=app.base, timeout=120)
        rig_id = demo_rig_ready(c)
        results["abuse"] = {**http_cases(app, rig_id), **socket_cases(app, rig_id)}
        results["abuse"]["token_redacted_in_access_log"] = token_redacted_case(app)
        results["load"] = load(app, 50, 15 if q else 60)
        results["load"]["detector"] = "combined (YuNet model installed)" if yunet.is_file() else "the paper's (no model)"
        print(f"  load: {results['load']['requests']} requests, p95 {results['load']['p95_ms']} ms", flush=True)
        rss = {"abuse_and_load": status_mb(app.proc.pid, "VmHWM")}
    key = "robustness-key"
    fuzz_dir = tempfile.mkdtemp(prefix="sc-robust-fuzz-")
    with serve_app({**FUZZ_SERVER_ENV, "SWEEPCAST_DATA_DIR": fuzz_dir, "SWEEPCAST_API_KEYS": key},
                   log=Path(fuzz_dir) / "api.log") as app:
        results["abuse"]["api_key_checked_before_body"] = body_before_auth_case(app)
        results["fuzz"] = fuzz(app, key, 20 if q else 150, seed=20261125)
        print(f"  fuzz: {results['fuzz']['cases']} cases, {results['fuzz']['server_errors']} server errors", flush=True)
        rss["fuzz"] = status_mb(app.proc.pid, "VmHWM")
    results["api_peak_rss_mb"] = rss
    results["kill_cycles"] = kill_cycles(3 if q else 10, 8)
    print(json.dumps(results["kill_cycles"]), flush=True)
    return results, markdown(results)


def bench_tenants(args: argparse.Namespace) -> tuple[dict, str]:
    """The part robustness_tenants (:mod:`benchmarks._tenants`)."""
    found = _tenants.tenants(args.quick)
    return found, _tenants.markdown(found)


def bench_sync_work(_args: argparse.Namespace) -> tuple[dict, str]:
    """The part robustness_sync_work (:mod:`benchmarks._sync_work`)."""
    found = _sync_work.sync_work()
    return found, _sync_work.markdown(found)


def bound_held(found: dict) -> bool:
    """The 49 MP requests were refused (413) and the 4K one within the bound was served."""
    refused = {a["status"] for a in found["bounded"]["one_49mp"]["answers"]} == {413}
    return refused and found["bounded"]["within_bound_4k"]["answers"][0]["status"] == 200


sections = Sections("robustness", __doc__)
sections.parser.add_argument("--quick", action="store_true", help="fewer repetitions, cases, clients and cycles")
sections.part("service", "kernel stress, abuse cases, fuzzing, load, kill cycles", bench_service, results="robustness")
sections.part("tenants", "owners, keys and quotas: cross-key probes, quota probes, the owner filter's cost",
              bench_tenants, check=lambda found: found["cross_key"]["all_404"] and found["cross_key"]["sockets_refused"])
sections.part("sync_work", "the synchronous routes' bound (49 MP depth requests)", bench_sync_work, check=bound_held)


if __name__ == "__main__":
    raise SystemExit(sections.main())
