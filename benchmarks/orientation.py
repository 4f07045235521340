"""EXIF orientation fixer benchmark (Shima & Shukuya): Tables I-III on real photos, and photos per second.

Accuracy. Every image in ``$SWEEPCAST_DATA/faces/dev`` (all subfolders) is turned by each of the
four rotations and re-encoded as a JPEG (quality 95), and each detector configuration decides
which way is up. A trial is a *success* when the decided rotation undoes the turn, a *reject*
when the detector declines, and *wrong* (the paper's "error") otherwise. ``dogs.jpg`` is a
negative (dog faces, no people): any decision on it is counted separately. As in the paper we
report Table I (acceptance per view, relative to the upright photo), Table II (how many of the
four views were accepted) and Table III (success / reject / error). Configurations:

- ``paper``: Haar whole face + Haar facial parts shipped with OpenCV (the product's default
  without a YuNet model);
- ``paper_mcs``: the paper's exact part cascades (haarcascade_mcs_*, CC BY-NC 4.0, from
  ``../shared/models/haar_mcs``; benchmark only);
- ``yunet``: YuNet alone with the per-face margin rule;
- ``combined``: YuNet faces confirmed by Haar parts or by a decisive YuNet margin (the default
  when a YuNet model is configured).

Per photo (``--text-section``, section orientation_text; issue 54): what a photo costs and what is decided, by class
(faces, text, neither faces nor text: the text photos of ``$SWEEPCAST_DATA/orientation/text`` and Leptonica's pages,
the no-text set of :mod:`benchmarks._notext`), this checkout beside the previous release, each engine in a process of
its own, and the text-line gate's recall and cost (:mod:`benchmarks._orientation_cost`).

Faces of every size (``--face-sizes``, section orientation_face_sizes; issue 33): the paper's detector with the Haar
scans of the last releases and the short-side rule on the dev faces scaled to 5-45 % of a 2048 x 1365 photo
(:mod:`benchmarks._face_sizes`).

Speed. ~12-megapixel JPEGs are made by upscaling dev photos. Engine only: ``analyze`` in-process
on one thread and on two threads (OpenCV releases the GIL), with decoding alone timed in the
same run as the baseline. End to end: the service is started as a subprocess
(``python -m app serve``), and a few concurrent clients POST the photos to
``/v1/photos/orientation`` (the clients run on the same machine and take their share of its CPU, which is
counted: the server's, the clients' and everything else's CPU per photo); the server's start-up work (kernel
warm-up from the checkout's kernel cache, ``sweepcast-data/cache/numba``, demo rig, Ray) finishes first; after one warm-up pass (reported
apart), photos per second is the median over repeats, each pass at least two requests per client.

Writers (``--writers``, section orientation_writers). Every real file of ``$SWEEPCAST_DATA/exif`` and
``orientation/formats`` in a format we write (JPEG, TIFF, PNG), plus generated TIFFs without the tag, is
given a new Orientation by each writer: ours (byte-level IFD0 edit for JPEG/TIFF; ExifTool for PNG, the
product's choice), Exiv2 through pyexiv2 (in memory, ``ImageData``; the bench extra) and ExifTool
(``-stay_open``, and one process per file). Per writer and format: files whose new tag reads back,
bytes changed (differing bytes when the length is kept, else the changed span before plus after) and
median milliseconds per file. A writer of ours is kept only where it wins on bytes or time.

Run: ``python -m benchmarks.orientation [--quick] [--no-http] [--no-speed]`` from the repository root;
``python -m benchmarks.orientation --text-section`` for the text cue alone (section orientation_text);
``python -m benchmarks.orientation --face-sizes`` for the Haar scans on faces of every size;
``python -m benchmarks.orientation --writers`` for the writers section alone;
``python -m benchmarks.orientation --throughput`` for issue 21's throughput alone (section orientation_throughput:
engines vs HTTP at 4 and 50 concurrent clients, ``/healthz`` latency under that load).
"""
from __future__ import annotations

import argparse
import concurrent.futures
import os
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from harness.proc import machine_busy_seconds
from benchmarks._report import md_table, prog, publish
from benchmarks._timing import load_note, settle_server
from harness.servers import CHECKOUT_KERNEL_CACHE, exit_on_sigterm, serve_app
from workers.common.datasets import data_root, dataset
from workers.orientation.decode import decode_gray
from workers.orientation.detect import (DetectorConfig, OrientationDetector, PaperDetector,
                                        get_detector)
from workers.orientation.geometry import ROTATIONS, rotate_view
from workers.orientation.faces import LongSideScan, ShortSideScan
from workers.orientation.parts import PartSpec
from workers.orientation.orient import analyze
from workers.orientation.detect import Engine

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".webp")
NEGATIVES = {"dogs.jpg"}
PAPER = {"success_rate": 0.931, "reject_rate": 0.069, "wrong": 0, "samples": 450}
MEGAPIXELS = 12.0
ROOT = Path(__file__).resolve().parents[1]
# Paper's Table I columns, as clockwise views of the upright photo.
TABLE1_COLUMNS = ((0, "0"), (270, "90 CCW"), (180, "180"), (90, "90 CW"))


@dataclass
class Tally:
    """Outcomes of one configuration over all trials."""

    success: int = 0
    reject: int = 0
    wrong: int = 0
    negative_trials: int = 0
    negative_decided: int = 0
    negative_decided_wrong_rotation: int = 0
    view_accepts: dict[int, int] = field(default_factory=lambda: {r: 0 for r in ROTATIONS})
    accept_counts: list[int] = field(default_factory=lambda: [0] * 5)
    wrong_cases: list[str] = field(default_factory=list)
    ms: list[float] = field(default_factory=list)

    @property
    def trials(self) -> int:
        return self.success + self.reject + self.wrong

    def summary(self) -> dict:
        n = max(self.trials, 1)
        return {
            "trials": self.trials, "success": self.success, "reject": self.reject, "wrong": self.wrong,
            "success_rate": self.success / n, "reject_rate": self.reject / n, "wrong_rate": self.wrong / n,
            "negative_trials": self.negative_trials, "negative_decided": self.negative_decided,
            "negative_decided_wrong_rotation": self.negative_decided_wrong_rotation,
            "table1_view_accepts": {label: self.view_accepts[r] for r, label in TABLE1_COLUMNS},
            "table2_accepted_views": {str(k): v for k, v in enumerate(self.accept_counts)},
            "wrong_cases": self.wrong_cases,
            "median_ms_per_photo": statistics.median(self.ms) if self.ms else None,
        }


def find_photos(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def configurations(yunet: Path | None, mcs: Path | None) -> dict[str, DetectorConfig]:
    """The face detectors of Tables I-III (faces only: the text cue off)."""
    configs = {"paper": DetectorConfig(method="paper", text=False)}
    if mcs is not None:
        configs["paper_mcs"] = DetectorConfig(method="paper", haar_mcs_dir=mcs, text=False)
    if yunet is not None:
        configs["yunet"] = DetectorConfig(method="yunet", yunet_model=yunet, text=False)
        configs["combined"] = DetectorConfig(method="combined", yunet_model=yunet, text=False)
    return configs


def load_photo(path: Path, megapixels: float | None = None) -> np.ndarray:
    """The stored pixels of ``path`` (BGR), upscaled (bicubic) to about ``megapixels`` if given."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
    if megapixels is None:
        return image
    s = (megapixels * 1e6 / (image.shape[0] * image.shape[1])) ** 0.5
    return cv2.resize(image, None, fx=s, fy=s, interpolation=cv2.INTER_CUBIC)


def rotated_inputs(path: Path, megapixels: float | None = None, quality: int = 95) -> dict[int, bytes]:
    """The photo turned so that rotating it ``r`` degrees clockwise makes it upright, as JPEG bytes."""
    image = load_photo(path, megapixels)
    out = {}
    for r in ROTATIONS:
        ok, buf = cv2.imencode(".jpg", rotate_view(image, (360 - r) % 360), [cv2.IMWRITE_JPEG_QUALITY, quality])
        assert ok
        out[r] = buf.tobytes()
    return out


def run_accuracy(photos: list[Path], detectors: dict[str, OrientationDetector],
                 megapixels: float | None = None) -> dict[str, Tally]:
    """Every photo x 4 rotations through every detector (optionally upscaled to ``megapixels``)."""
    tallies = {name: Tally() for name in detectors}
    for i, path in enumerate(photos):
        inputs = rotated_inputs(path, megapixels, 95 if megapixels is None else 90)
        negative = path.name in NEGATIVES
        line = []
        for name, detector in detectors.items():
            t = tallies[name]
            marks = ""
            for r, data in inputs.items():
                report = analyze(data, detector)
                t.ms.append(report.elapsed_ms)
                if negative:  # a decision is not a face result; still, it must not turn the photo wrongly
                    t.negative_trials += 1
                    t.negative_decided += report.rotation_degrees is not None
                    t.negative_decided_wrong_rotation += report.rotation_degrees not in (None, r)
                    marks += "n" if report.rotation_degrees is None else ("d" if report.rotation_degrees == r else "X")
                    continue
                for a in report.accepted_rotations:
                    t.view_accepts[(a - r) % 360] += 1
                t.accept_counts[len(report.accepted_rotations)] += 1
                if report.rotation_degrees == r:
                    t.success += 1
                    marks += "+"
                elif report.rotation_degrees is None:
                    t.reject += 1
                    marks += "."
                else:
                    t.wrong += 1
                    t.wrong_cases.append(f"{path.name} turned {r}: decided {report.rotation_degrees}")
                    marks += "X"
            line.append(f"{name}:{marks}")
        print(f"[{i + 1}/{len(photos)}] {path.name[:40]:40s} " + " ".join(line), flush=True)
    return tallies


def make_large_jpegs(photos: list[Path], count: int) -> list[bytes]:
    """``count`` face photos upscaled to ~12 MP (bicubic) and encoded as JPEG quality 90."""
    faces = [p for p in photos if p.name not in NEGATIVES]
    out = []
    for i in np.linspace(0, len(faces) - 1, min(count, len(faces))).round().astype(int):  # spread over the set
        path = faces[i]
        ok, buf = cv2.imencode(".jpg", load_photo(path, MEGAPIXELS), [cv2.IMWRITE_JPEG_QUALITY, 90])
        assert ok
        out.append(buf.tobytes())
    return out


def rate(fn, items: list[bytes], threads: int, repeats: int) -> float:
    """Median items per second of ``fn`` over ``repeats`` passes with ``threads`` workers."""
    rates = []
    with concurrent.futures.ThreadPoolExecutor(threads) as pool:
        list(pool.map(fn, items[:2 * threads]))  # untimed: builds each thread's detectors
        for _ in range(repeats):
            start = time.perf_counter()
            list(pool.map(fn, items))
            rates.append(len(items) / (time.perf_counter() - start))
    return statistics.median(rates)


def cpu_ms_per_photo(fn, items: list[bytes]) -> float:
    """Median CPU time (ms, this thread, OpenCV single-threaded) of ``fn`` per item: unlike wall time it
    barely depends on other processes, so ``2000 / cpu_ms`` estimates photos/s on 2 idle cores."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    fn(items[0])
    times = []
    for item in items:
        start = time.thread_time()
        fn(item)
        times.append(1000 * (time.thread_time() - start))
    cv2.setNumThreads(threads)
    return statistics.median(times)


def run_engine_speed(large: list[bytes], detectors: dict[str, OrientationDetector], repeats: int) -> dict:
    """Photos per second of ``analyze`` in this process: 1 and 2 worker threads, with OpenCV's own
    thread pool on (default) and off (``cv2.setNumThreads(1)``, one core per photo)."""
    default_threads = cv2.getNumThreads()
    out: dict = {"decode_only_photos_per_s_1thread": rate(decode_gray, large, 1, repeats)}
    for name, detector in detectors.items():
        out[name] = {"cpu_ms_per_photo": cpu_ms_per_photo(lambda d: analyze(d, detector), large)}
        for cv_threads, tag in ((default_threads, ""), (1, "_cv1")):
            cv2.setNumThreads(cv_threads)
            for k in (1, 2):
                cpu = time.process_time()
                out[name][f"photos_per_s_{k}thread{tag}"] = rate(lambda d: analyze(d, detector), large, k, repeats)
                if k == 2 and tag == "_cv1":  # CPU per photo with two photos at a time, as a served app runs them
                    done = min(len(large), 2 * k) + repeats * len(large)
                    out[name]["cpu_ms_per_photo_2thread"] = 1000 * (time.process_time() - cpu) / done
        cv2.setNumThreads(default_threads)
        print(f"engine {name}: {out[name]}", flush=True)
    return out


def run_http_speed(large: list[bytes], yunet: Path | None, clients: int | list[int], repeats: int,
                   text: bool = True) -> dict:
    """Photos per second through ``POST /v1/photos/orientation`` of a real server subprocess; with a list
    of client counts, one result per count (same server), each with ``/healthz`` latency meanwhile.
    ``text`` False: the server's text cue off (the faces alone). The server's start-up work is left to finish
    first (:func:`_settle`): its numba kernels come from the checkout's cache (``sweepcast-data/cache/numba``), as in a
    service that has started before, so no compile shares the cores with the photos."""
    import httpx

    with tempfile.TemporaryDirectory(prefix="sweepcast-bench-") as tmp:
        # fetching stays off (serve_app): the paper run must not pick up a fetched model
        env = {"SWEEPCAST_DATA_DIR": tmp, "SWEEPCAST_ORIENTATION_YUNET_MODEL": str(yunet) if yunet else None,
               "SWEEPCAST_NUMBA_CACHE_DIR": str(CHECKOUT_KERNEL_CACHE)}
        if not text:
            env["SWEEPCAST_ORIENTATION_TEXT"] = "false"
        try:
            with serve_app(env, log=Path(tmp) / "server.log") as app:
                settle = _settle(app.base, app.proc.pid)
                if isinstance(clients, int):
                    return {**_post_all(app.base, app.proc.pid, large, clients, repeats, httpx), "settle": settle}
                return {str(n): {**_post_all(app.base, app.proc.pid, large, n, repeats, httpx, healthz=True),
                                 "settle": settle} for n in clients}
        except RuntimeError as exc:
            return {"error": str(exc)}


def _proc_cpu_s(pid: int, tree: bool) -> float:
    """CPU seconds (user + system) process ``pid`` has used; ``tree``: with every live descendant (the server's
    Ray processes, its kernel warm-up) and the children they reaped."""
    tick = os.sysconf("SC_CLK_TCK")
    stats: dict[int, tuple[int, float]] = {}
    for path in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = path.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        # fields[1] is the parent pid; utime, stime, cutime, cstime are fields[11:15]
        stats[int(path.parent.name)] = (int(fields[1]), sum(int(v) for v in fields[11:15]) / tick)
    if not tree:
        return stats.get(pid, (0, 0.0))[1]
    members, frontier = {pid}, [pid]
    while frontier:
        parent = frontier.pop()
        kids = [p for p, (ppid, _) in stats.items() if ppid == parent and p not in members]
        members.update(kids)
        frontier += kids
    return sum(stats[p][1] for p in members if p in stats)


def _settle(base: str, pid: int) -> dict:
    """Wait until the served app's start-up work is done (:func:`benchmarks._timing.settle_server`: the server's
    process tree below 0.1 core over one second)."""
    return settle_server(base, pid, lambda p: _proc_cpu_s(p, tree=True), interval_s=1.0, timeout_s=300.0)


def _multipart(data: bytes, boundary: str) -> bytes:
    """A ``multipart/form-data`` body with ``data`` as the part ``file`` (photo.jpg, image/jpeg)."""
    head = (f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="photo.jpg"\r\n'
            "Content-Type: image/jpeg\r\n\r\n").encode()
    return head + data + f"\r\n--{boundary}--\r\n".encode()


def _post_all(base: str, pid: int, large: list[bytes], clients: int, repeats: int, httpx,
              healthz: bool = False) -> dict:
    """``repeats`` timed passes (after a warm-up pass) of ``clients`` threads posting the photos, each pass
    ``max(2 * len(large), 2 * clients)`` requests (the photos in turn), so that every client has requests
    in flight. Request bodies are built once, before the clock: the clients share the machine's cores
    with the server, and their CPU (this process), the server's (its own process; its process tree) and
    the whole machine's are counted over the timed passes."""
    url = f"{base}/v1/photos/orientation"
    probe = _HealthProbe(f"{base}/healthz", httpx) if healthz else None
    local = __import__("threading").local()
    latencies: list[float] = []
    decisions: dict[str, int] = {}
    boundary = "sweepcast-bench-boundary"
    headers = {"content-type": f"multipart/form-data; boundary={boundary}"}
    bodies = [_multipart(data, boundary) for data in large]
    per_pass = max(2 * len(bodies), 2 * clients)
    work = [bodies[i % len(bodies)] for i in range(per_pass)]

    def post(body: bytes) -> None:
        client = getattr(local, "client", None)
        if client is None:
            client = local.client = httpx.Client(timeout=300.0)
        start = time.perf_counter()
        response = client.post(url, content=body, headers=headers)
        latencies.append(time.perf_counter() - start)
        if response.status_code != 200:
            raise RuntimeError(f"POST {url} -> {response.status_code}: {response.text[:300]}")
        decision = response.json()["decision"]
        decisions[decision] = decisions.get(decision, 0) + 1

    rates = []
    with concurrent.futures.ThreadPoolExecutor(clients) as pool:
        # the first pass is the warm-up (each server thread builds its detector, the connections open): timed
        # and reported apart; photos_per_s is the median of the passes after it (steady state)
        start = time.perf_counter()
        list(pool.map(post, work))
        first = len(work) / (time.perf_counter() - start)
        latencies.clear()
        decisions.clear()
        if probe is not None:
            probe.start()
        cpu0 = (_proc_cpu_s(pid, tree=False), _proc_cpu_s(pid, tree=True), time.process_time(), machine_busy_seconds(),
                time.perf_counter())
        for _ in range(repeats):
            start = time.perf_counter()
            list(pool.map(post, work))
            rates.append(len(work) / (time.perf_counter() - start))
        cpu1 = (_proc_cpu_s(pid, tree=False), _proc_cpu_s(pid, tree=True), time.process_time(), machine_busy_seconds(),
                time.perf_counter())
    health = probe.stop() if probe is not None else None
    photos = len(work) * repeats
    server, tree, client, machine, wall = (b - a for a, b in zip(cpu0, cpu1))
    cpu = {"server_cpu_ms_per_photo": 1000 * server / photos, "server_tree_cpu_ms_per_photo": 1000 * tree / photos,
           "client_cpu_ms_per_photo": 1000 * client / photos, "machine_busy_cores": machine / wall,
           "other_cpu_ms_per_photo": 1000 * (machine - tree - client) / photos}
    return {"photos_per_s": statistics.median(rates), "rates": rates, "first_pass_photos_per_s": first,
            "clients": clients, "requests_per_pass": per_pass, "median_latency_ms": 1000 * statistics.median(latencies),
            "decisions": decisions, **cpu, **({"healthz": health} if health else {})}


class _HealthProbe:
    """``GET /healthz`` every 50 ms on its own connection while the photos are posted: latency p50/p99 (ms)."""

    def __init__(self, url: str, httpx) -> None:
        import threading

        self.url, self.httpx = url, httpx
        self.times: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        with self.httpx.Client(timeout=30.0) as client:
            while not self._stop.is_set():
                t = time.perf_counter()
                client.get(self.url).raise_for_status()
                self.times.append(1000 * (time.perf_counter() - t))
                self._stop.wait(0.05)

    def stop(self) -> dict:
        self._stop.set()
        self._thread.join()
        return {"probes": len(self.times), "p50_ms": float(np.percentile(self.times, 50)),
                "p99_ms": float(np.percentile(self.times, 99)), "max_ms": float(max(self.times))}


THROUGHPUT_CLIENTS = (4, 50)
PREV_HAAR = {"scan": LongSideScan(320, 20), "scale_factor": 1.2, "min_neighbors": 3, "second": None}
"""The paper detector's Haar face search before issue 21's speed-up (same decisions on the dev photos)."""


def no_face_cost(yunet: Path | None, count: int = 6) -> dict | None:
    """CPU ms per 12 MP photo with neither a face nor an up (``$SWEEPCAST_DATA/orientation/noup``: textures,
    aerial and microscope images) through the service's default engine with its text cue on: what a photo
    organiser's landscapes cost, since the text cue runs whenever the faces decide nothing."""
    root = dataset("orientation")
    paths = find_photos(root / "noup") if root is not None else []
    if not paths:
        return None
    photos = make_large_jpegs(paths, count)
    engine = get_detector(DetectorConfig(yunet_model=yunet, text=True))
    return {"engine": engine.name, "photos": len(photos), "text_cue": engine.text_info.get("available"),
            "cpu_ms_per_photo": cpu_ms_per_photo(lambda d: analyze(d, engine), photos)}


def run_throughput(photos: list[Path], yunet: Path | None, repeats: int) -> int:
    """Section orientation_throughput (issue 21): 12 MP JPEGs through the engines in this process (the
    anchor) and over HTTP with 4 and 50 concurrent clients, /healthz latency meanwhile; the paper's
    detector alone (text cue off) and the service's default (combined, text cue on)."""
    load_before = os.getloadavg()[0]
    large = make_large_jpegs(photos, 12)
    engines = {"paper": get_detector(DetectorConfig(yunet_model=None, text=False)),
               # the anchor of the Haar search's speed-up, measured under the same load
               "paper_prev_search": Engine(PaperDetector(PartSpec.opencv(), name="paper_prev_search", **PREV_HAAR), None)}
    if yunet is not None:
        engines["combined"] = get_detector(DetectorConfig(yunet_model=yunet, text=False))
    results: dict = {"photos": len(large), "megapixels": MEGAPIXELS, "repeats": repeats,
                     "mean_megabytes": float(np.mean([len(b) for b in large]) / 1e6), "load_average_before": load_before,
                     "engine": run_engine_speed(large, engines, repeats), "http": {}}
    results["engine"]["decode_cpu_ms_per_photo"] = cpu_ms_per_photo(decode_gray, large)
    results["no_face"] = no_face_cost(yunet)
    servers = {"paper": (None, False)} | ({"combined": (yunet, True)} if yunet is not None else {})
    for name, (model, text) in servers.items():
        results["http"][name] = run_http_speed(large, model, list(THROUGHPUT_CLIENTS), repeats, text=text)
        print(f"http {name}: {results['http'][name]}", flush=True)
    results["load_average_after"] = os.getloadavg()[0]
    rows = []
    for name, e in results["engine"].items():
        if not isinstance(e, dict):
            continue
        label = (f"engine paper, previous face search ({PREV_HAAR['scan'].scan_size} px, step {PREV_HAAR['scale_factor']}, "
                 f"{PREV_HAAR['min_neighbors']} neighbours)" if name == "paper_prev_search" else f"engine {name}")
        rows.append([label, e["photos_per_s_1thread_cv1"], e["photos_per_s_2thread_cv1"],
                     f"{e['cpu_ms_per_photo']:.0f} ms CPU/photo one at a time (2 idle cores: "
                     f"~{2000 / e['cpu_ms_per_photo']:.0f}/s), {e['cpu_ms_per_photo_2thread']:.0f} two at a time", "-"])
    for name, by_clients in results["http"].items():
        if "error" in by_clients:
            rows.append([f"HTTP {name}", "-", "-", by_clients["error"][:80], "-"])
            continue
        engine = results["engine"].get(name, {})
        for n, r in by_clients.items():
            h = r["healthz"]
            server = r["server_cpu_ms_per_photo"]
            vs = (f" = {engine['cpu_ms_per_photo_2thread'] / server:.2f}x the engine's efficiency (its "
                  f"{engine['cpu_ms_per_photo_2thread']:.0f} ms CPU/photo on 2 threads); "
                  f"{r['photos_per_s'] / engine['photos_per_s_2thread_cv1']:.2f}x its 2-thread rate") if engine else ""
            rows.append([f"HTTP {name}, {n} clients", "-", r["photos_per_s"],
                         f"server {server:.0f} ms CPU/photo ({r['server_tree_cpu_ms_per_photo']:.0f} with its child "
                         f"processes){vs}; clients {r['client_cpu_ms_per_photo']:.0f} ms CPU/photo, other work "
                         f"{r['other_cpu_ms_per_photo']:.0f}; machine {r['machine_busy_cores']:.2f} of 2 cores busy; "
                         f"median latency {r['median_latency_ms']:.0f} ms",
                         f"{h['p50_ms']:.0f} / {h['p99_ms']:.0f}"])
    no_face = results["no_face"]
    if no_face:
        rows.append([f"engine {no_face['engine']}, text cue on, photos without faces", "-", "-",
                     f"{no_face['cpu_ms_per_photo']:.0f} ms CPU/photo (2 idle cores: ~{2000 / no_face['cpu_ms_per_photo']:.1f}/s)"
                     f"; {no_face['photos']} noup/ photos at ~{MEGAPIXELS:.0f} MP, all four views read for text", "-"])
    busy = load_before > 0.5
    publish("orientation_throughput", results, (
        f"{len(large)} face photos upscaled to ~{MEGAPIXELS:.0f} MP, JPEG q90 ({results['mean_megabytes']:.1f} MB each). "
        "Engine: `analyze` in this process, OpenCV single-threaded per photo, 1 and 2 worker threads (the anchor). "
        "HTTP: `POST /v1/photos/orientation` on a served app (its start-up work finished first, kernels from the "
        "checkout's cache), 4 and 50 concurrent clients each with requests in flight (a pass is max(24, 2 x clients) "
        "requests, bodies built before the clock), median of the passes after a warm-up pass; `/healthz` probed every "
        "50 ms meanwhile. The clients run on the same 2 cores: CPU per photo is counted for the server process (and "
        "with its child processes: Ray, warm-up), the clients (this process) and everything else on the machine; "
        "'x the engine's efficiency' is the engine's CPU per photo (two photos at a time, as the server's two "
        "compute threads run them: on this machine's 2 cores one photo costs more CPU time while another runs) over "
        "the server's (1.00: the HTTP path adds nothing), the fair figure when the clients share the cores. "
        "Paper: Haar faces + parts, text cue off "
        "(the detector alone); combined: the service's default (YuNet + parts, paper fallback, text cue on). "
        f"JPEG decoding alone: {results['engine']['decode_cpu_ms_per_photo']:.1f} ms CPU per photo (DCT-scaled to <= 900 px). "
        f"The paper detector's face search takes {results['engine']['paper_prev_search']['cpu_ms_per_photo'] / results['engine']['paper']['cpu_ms_per_photo']:.2f}x "
        "less CPU per photo than the previous one in this run (same decisions on the dev photos: section orientation). "
        + load_note(load_before, results["load_average_after"])
        + (" At such a load every rate here is low, and even CPU ms per photo grows under contention; compare "
           "ratios within this table, not with quiet runs." if busy else "") + "\n\n"
        + md_table(["path", "photos/s 1 thread", "photos/s 2 threads / HTTP", "note", "/healthz p50 / p99 ms"], rows)
        + "\n" + throughput_goals(results)))
    return 0


def throughput_goals(results: dict) -> str:
    """Issue 21's orientation goals, met or not, each with the measured limit where not."""
    eng, http = results["engine"], results["http"]
    paper = eng["paper"]["photos_per_s_2thread_cv1"]
    lines = [f"- The paper's detector alone >= 15 photos/s: {paper:.1f}/s on 2 threads: "
             f"**{'met' if paper >= 15 else 'not met'}**."]
    combined, served = eng.get("combined"), http.get("combined", {}).get("50")
    if combined and served:
        cap = 2000 / combined["cpu_ms_per_photo_2thread"]
        lines.append(f"- Over HTTP >= 50 photos/s (combined, 50 clients): {served['photos_per_s']:.1f}/s: "
                     f"**{'met' if served['photos_per_s'] >= 50 else 'not met'}**."
                     + ("" if served["photos_per_s"] >= 50 else
                        f" Limit: the engine. Two photos at a time cost {combined['cpu_ms_per_photo_2thread']:.0f} ms "
                        f"of CPU each, so 2 cores give at most {cap:.0f}/s before any HTTP (the engine measured "
                        f"{combined['photos_per_s_2thread_cv1']:.1f}/s on 2 threads)."))
        extra = served["server_cpu_ms_per_photo"] - combined["cpu_ms_per_photo_2thread"]
        lines.append(f"- 50 clients at the engine's throughput: the server spends {served['server_cpu_ms_per_photo']:.0f} "
                     f"ms of CPU per photo against the engine's {combined['cpu_ms_per_photo_2thread']:.0f} "
                     f"({combined['cpu_ms_per_photo_2thread'] / served['server_cpu_ms_per_photo']:.2f}x its efficiency); "
                     f"the {extra:.0f} ms more per photo is the HTTP path itself (receiving the 12 MP upload, the "
                     "multipart parser, JSON, the hand-off to the compute threads), and the clients share the same "
                     f"2 cores ({served['client_cpu_ms_per_photo']:.0f} ms CPU per photo).")
        worst = max(r["healthz"]["p99_ms"] for by in http.values() if "error" not in by for r in by.values())
        lines.append(f"- /healthz p99 < 100 ms meanwhile: worst p99 {worst:.0f} ms: "
                     f"**{'met' if worst < 100 else 'not met'}**.")
    return "\nGoals (issue 21):\n\n" + "\n".join(lines) + "\n"


FACE_SIZE_TURNS = (0, 270)
"""Turns of each face-size variant tried (upright and a quarter turn: a landscape scanned as a portrait too; the
Haar search sees all four views in every trial)."""


def face_size_configs() -> dict[str, tuple]:
    """The Haar searches compared on faces of every size: the releases' fixed long sides, the rule (short side) alone,
    and the engine's (the rule, then the previous release's search on a photo the rule found no face in); each as
    (scan, pyramid step, neighbours, second search)."""
    from workers.orientation.detect import (HAAR_FACE_PX, HAAR_MIN_NEIGHBORS, HAAR_SCALE_FACTOR, HAAR_SECOND_SEARCH,
                                            HAAR_SMALLEST_FACE, PREVIOUS_HAAR)

    rule = f"rule: 1/{round(1 / HAAR_SMALLEST_FACE)} of the short side at {HAAR_FACE_PX} px"
    scan = ShortSideScan(HAAR_SMALLEST_FACE, HAAR_FACE_PX)
    return {
        "400 px long side (two releases ago)": (LongSideScan(400, 20), 1.2, 3, None),
        "320 px long side (the regression)": (LongSideScan(320, 20), 1.2, 3, None),
        "360 px long side (previous release)": (*PREVIOUS_HAAR, None),
        f"{rule}, step 1.35": (scan, 1.35, HAAR_MIN_NEIGHBORS, None),
        f"{rule} ({round(HAAR_FACE_PX / HAAR_SMALLEST_FACE)} px short side), step {HAAR_SCALE_FACTOR}, alone": (
            scan, HAAR_SCALE_FACTOR, HAAR_MIN_NEIGHBORS, None),
        f"{rule}, step {HAAR_SCALE_FACTOR}, then the 360 px search where it finds no face (engine)": (
            scan, HAAR_SCALE_FACTOR, HAAR_MIN_NEIGHBORS, HAAR_SECOND_SEARCH),
    }


def run_face_sizes(photos: list[Path], yunet: Path) -> dict:
    """Section orientation_face_sizes: every Haar scan on the face-size set (:mod:`benchmarks._face_sizes`), the
    paper's detector alone (Haar face + parts; text off): decided / wrong per face share, CPU ms per photo."""
    from benchmarks._face_sizes import CANVAS, FACE_SHARES, face_size_set

    load_before = os.getloadavg()[0]
    cv2.setNumThreads(1)
    configs = {name: PaperDetector(PartSpec.opencv(), name=name, scan=scan, scale_factor=step, min_neighbors=n,
                                   second=second)
               for name, (scan, step, n, second) in face_size_configs().items()}
    cells: dict = {name: {str(sh): {"trials": 0, "decided": 0, "wrong": 0} for sh in FACE_SHARES} for name in configs}
    cpu: dict = {name: [] for name in configs}
    photos_used: set = set()
    for name_photo, share, image in face_size_set([p for p in photos if p.name not in NEGATIVES], yunet):
        photos_used.add(name_photo)
        for turn in FACE_SIZE_TURNS:
            ok, buf = cv2.imencode(".jpg", rotate_view(image, (360 - turn) % 360), [cv2.IMWRITE_JPEG_QUALITY, 90])
            data = buf.tobytes()
            marks = ""
            for name, detector in configs.items():
                start = time.thread_time()
                report = analyze(data, detector)
                cpu[name].append(1000 * (time.thread_time() - start))
                cell = cells[name][str(share)]
                cell["trials"] += 1
                cell["decided"] += report.rotation_degrees == turn
                cell["wrong"] += report.rotation_degrees not in (None, turn)
                marks += "+" if report.rotation_degrees == turn else "." if report.rotation_degrees is None else "X"
            print(f"{name_photo[:36]:36s} share {share:.2f} turn {turn:3d} {marks}", flush=True)
    dev = {name: {"trials": 0, "decided": 0, "wrong": 0} for name in configs if _dev_config(name)}
    for path in [p for p in photos if p.name not in NEGATIVES]:
        for turn, data in rotated_inputs(path).items():
            for name in dev:
                got = analyze(data, configs[name]).rotation_degrees
                dev[name]["trials"] += 1
                dev[name]["decided"] += got == turn
                dev[name]["wrong"] += got not in (None, turn)
    return {"canvas": list(CANVAS), "shares": list(FACE_SHARES), "turns": list(FACE_SIZE_TURNS),
            "photos": len(photos_used), "cells": cells, "dev_photos": dev,
            "cpu_ms_per_photo": {n: statistics.median(v) for n, v in cpu.items()},
            "load_average_before": load_before, "load_average_after": os.getloadavg()[0]}


def _dev_config(name: str) -> bool:
    """The searches also run on the dev photos as they are: the previous release's, the rule alone and the engine's."""
    return "previous release" in name or name.endswith(("engine)", "alone"))


def face_sizes_markdown(result: dict) -> str:
    shares = [str(s) for s in result["shares"]]
    h = min(result["canvas"])
    rows = []
    for name, by_share in result["cells"].items():
        total = sum(c["decided"] for c in by_share.values())
        trials = sum(c["trials"] for c in by_share.values())
        wrong = sum(c["wrong"] for c in by_share.values())
        rows.append([name, *[f"{by_share[s]['decided']}/{by_share[s]['trials']}" for s in shares],
                     f"{total}/{trials} ({100 * total / max(trials, 1):.1f}%)", wrong,
                     f"{result['cpu_ms_per_photo'][name]:.0f}"])
    names = list(result["cells"])
    engine = next(n for n in names if n.endswith("engine)"))
    previous = next(n for n in names if "previous release" in n)
    worse = [s for s in shares if result["cells"][engine][s]["decided"] < result["cells"][previous][s]["decided"]]
    dev = result["dev_photos"]
    if dev[engine]["decided"] < dev[previous]["decided"]:
        worse.append(f"the dev photos at native size ({dev[engine]['decided']} against {dev[previous]['decided']})")
    verdict = ("the engine decides at least as many trials as the previous release at every face size and on the "
               "dev photos at native size: **met**" if not worse else
               "the engine decides fewer trials than the previous release at face shares " + ", ".join(worse)
               + ": **not met**")
    return "\n".join([
        f"The paper's detector alone (Haar face + OpenCV's part cascades, text cue off) on faces of every size: the "
        f"{result['photos']} dev face photos with a YuNet face, each scaled so that its largest face is a given share "
        f"of the short side of a {result['canvas'][1]} x {h} photo (cut around the face, edge pixels repeated at the borders; "
        f"never enlarged more than 3x), turned {', '.join(map(str, result['turns']))} degrees, JPEG q90 (the engine "
        f"decodes it to <= 900 px). Cells: trials decided right / trials per face share (face width in the photo = "
        f"share x {h} px). CPU: median ms per photo (one thread, OpenCV single-threaded, decode included). "
        + load_note(result["load_average_before"], result["load_average_after"])
        + " CPU ms grow with the load: compare within the table.", "",
        md_table(["Haar search", *[f"{float(s):.2f} ({round(float(s) * h)} px)" for s in shares], "all", "wrong",
                  "CPU ms/photo"], rows), "",
        f"Faces never below the previous release: {verdict}.", "",
        "The same detector on the dev face photos as they are (native size, 4 turns, JPEG q95):", "",
        md_table(["Haar search", "decided", "wrong"], [[n, f"{c['decided']}/{c['trials']}", c["wrong"]]
                                                    for n, c in result["dev_photos"].items()])])


def markdown(results: dict) -> str:
    configs = results["configs"]
    def row(name: str, c: dict) -> list:
        return [name, c["trials"], c["success"], c["reject"], c["wrong"], f"{100 * c['success_rate']:.1f}%",
                f"{100 * c['reject_rate']:.1f}%",
                f"{c['negative_decided']}/{c['negative_trials']} ({c['negative_decided_wrong_rotation']} wrong)",
                c["median_ms_per_photo"]]

    rows = [row(name, c) for name, c in configs.items()]
    rows += [row(f"{name} at {MEGAPIXELS:.0f} MP", c) for name, c in results["configs_12mp"].items()]
    rows.append(["paper (Table III, 450 CALTECH faces)", PAPER["samples"], 419, 31, 0, "93.1%", "6.9%", "-", "-"])
    parts = [
        f"{results['dataset']['photos']} photos ({results['dataset']['faces']} with faces, "
        f"{results['dataset']['negatives']} negative) x 4 rotations, re-encoded as JPEG q95.",
        "",
        "Table III (success / reject / wrong). Negatives: decisions made on the dog photo's 4 rotations "
        "(and how many of them turned it wrongly). Rows 'at 12 MP': the photos upscaled to ~12 MP, JPEG q90.",
        "",
        md_table(["config", "trials", "success", "reject", "wrong", "success rate", "reject rate",
                  "negatives decided", "median ms/photo"], rows),
        "",
        "Table I (trials in which the view was accepted; views relative to the upright photo)",
        "",
        md_table(["config"] + [label for _, label in TABLE1_COLUMNS],
                 [[n] + list(c["table1_view_accepts"].values()) for n, c in configs.items()]),
        "",
        "Table II (number of accepted views per trial)",
        "",
        md_table(["config", "0", "1", "2", "3", "4"],
                 [[n] + list(c["table2_accepted_views"].values()) for n, c in configs.items()]),
    ]
    speed = results.get("speed")
    if speed:
        rows = []
        for name, e in speed["engine"].items():
            if isinstance(e, dict):
                rows.append([f"engine {name}", e["photos_per_s_1thread"], e["photos_per_s_2thread"],
                             "OpenCV threads on"])
                rows.append([f"engine {name}", e["photos_per_s_1thread_cv1"], e["photos_per_s_2thread_cv1"],
                             "cv2.setNumThreads(1)"])
                rows.append([f"engine {name}, CPU time", f"{e['cpu_ms_per_photo']:.0f} ms/photo",
                             f"~{2000 / e['cpu_ms_per_photo']:.1f} (estimate)", "2000 / CPU ms: two idle cores"])
        rows.append(["decode only", speed["engine"]["decode_only_photos_per_s_1thread"], "-", "-"])
        for name, h in speed["http"].items():
            if "error" in h:
                rows.append([f"HTTP {name}", "-", "-", f"not measured: {h['error'][:120]}"])
            else:
                rows.append([f"HTTP {name} ({h['clients']} clients)", "-", h["photos_per_s"],
                             f"median latency {h['median_latency_ms']:.0f} ms; passes "
                             + ", ".join(f"{r:.1f}" for r in h["rates"])
                             + f" (after a warm-up pass at {h['first_pass_photos_per_s']:.1f})"])
        parts += ["", f"Speed on {speed['photos']} JPEGs of ~{MEGAPIXELS:.0f} MP "
                      f"({speed['mean_megabytes']:.1f} MB each), photos per second (median of {speed['repeats']})",
                  "", md_table(["path", "1 thread", "2 threads / concurrent", "note"], rows)]
    return "\n".join(parts)


def changed_bytes(before: bytes, after: bytes) -> int:
    """Bytes a write changed: differing bytes when the length is kept, else the changed span of both versions
    (everything between the common prefix and the common suffix, before plus after)."""
    if len(before) == len(after):
        return int(np.count_nonzero(np.frombuffer(before, np.uint8) != np.frombuffer(after, np.uint8)))
    n = min(len(before), len(after))
    a, b = np.frombuffer(before[:n], np.uint8), np.frombuffer(after[:n], np.uint8)
    diff = np.nonzero(a != b)[0]
    prefix = int(diff[0]) if diff.size else n
    ra, rb = np.frombuffer(before[::-1][:n], np.uint8), np.frombuffer(after[::-1][:n], np.uint8)
    rdiff = np.nonzero(ra != rb)[0]
    suffix = min(int(rdiff[0]) if rdiff.size else n, n - prefix)
    span = (len(before) - prefix - suffix) + (len(after) - prefix - suffix)
    if len(after) > len(before):  # data appended at the end (a new IFD0): what changed in place, plus it
        kept = np.frombuffer(after[:len(before)], np.uint8) != np.frombuffer(before, np.uint8)
        span = min(span, int(np.count_nonzero(kept)) + len(after) - len(before))
    return span


def writer_inputs(quick: bool = False) -> dict[str, list[tuple[str, bytes]]]:
    """Real files per format we write (jpeg, tiff, png), plus generated TIFFs without an Orientation tag."""
    from harness.photos import gray_pages, tiff

    out: dict[str, list[tuple[str, bytes]]] = {"jpeg": [], "tiff": [], "png": []}
    for folder in (dataset("exif"), dataset("orientation", "formats")):
        if folder is None:
            continue
        for path in sorted(folder.rglob("*")):
            ext = path.suffix.lower()
            fmt = {".jpg": "jpeg", ".jpeg": "jpeg", ".tif": "tiff", ".tiff": "tiff", ".png": "png"}.get(ext)
            if fmt is not None and "bad_exif" not in path.name:
                out[fmt].append((path.name, path.read_bytes()))
    for endian in "<>":
        for pages in (1, 3):
            out["tiff"].append((f"generated_{'LE' if endian == '<' else 'BE'}_{pages}p_untagged.tif",
                                tiff(gray_pages(pages, 300, 400), endian)))
    if quick:
        out = {k: v[::3] for k, v in out.items()}
    return out


def run_writers(quick: bool = False) -> dict:
    """Each writer on each input (see the module docstring); returns per (format, writer) tallies."""
    import shutil
    import subprocess

    from workers.orientation import exiftool
    from workers.orientation.exif import write_orientation
    from workers.orientation.headers import parse_header
    from workers.orientation.metadata import inspect, write_png_orientation, write_tiff_orientation

    def via_exiftool_files(data: bytes, value: int, suffix: str, one_shot: bool) -> bytes:
        with tempfile.TemporaryDirectory() as tmp:
            src, dst = Path(tmp) / f"in{suffix}", Path(tmp) / f"out{suffix}"
            src.write_bytes(data)
            args = ["-q", "-m", "-n", f"-IFD0:Orientation={value}", "-o", str(dst), str(src)]
            if one_shot:
                subprocess.run(["exiftool", *args], check=True, capture_output=True)
            else:
                exiftool.run(args)
            return dst.read_bytes()

    def via_pyexiv2(data: bytes, value: int, suffix: str) -> bytes:
        import pyexiv2

        with pyexiv2.ImageData(data) as img:
            img.modify_exif({"Exif.Image.Orientation": value})
            return img.get_bytes()

    ours = {"jpeg": lambda d, v, s: write_orientation(d, v), "tiff": lambda d, v, s: write_tiff_orientation(d, v),
            "png": lambda d, v, s: write_png_orientation(d, v)}
    writers: dict[str, object] = {"sweepcast": None}
    import importlib.util

    if importlib.util.find_spec("pyexiv2") is not None:
        writers["exiv2 (pyexiv2)"] = via_pyexiv2
    else:
        print("note: pyexiv2 not installed (pip install '.[bench]'): Exiv2 not measured")
    has_exiftool = shutil.which("exiftool") is not None
    if has_exiftool:
        writers["exiftool -stay_open"] = lambda d, v, s: via_exiftool_files(d, v, s, False)
        writers["exiftool per file"] = lambda d, v, s: via_exiftool_files(d, v, s, True)
    inputs = writer_inputs(quick)
    rows = []
    for fmt, files in inputs.items():
        suffix = {"jpeg": ".jpg", "tiff": ".tif", "png": ".png"}[fmt]
        for name, fn in writers.items():
            fn = ours[fmt] if fn is None else fn
            if name == "sweepcast" and fmt == "png" and not has_exiftool:
                continue
            ok, changed, times, failures = 0, [], [], []
            for fname, data in files:
                value = 8 if inspect(data, parse_header(data)).shown() != 8 else 3
                try:
                    fn(data, value, suffix)  # warm-up (exiftool's first call starts Perl)
                    start = time.perf_counter()
                    out = fn(data, value, suffix)
                    times.append((time.perf_counter() - start) * 1000)
                except Exception as exc:  # noqa: BLE001 - a library refusing a file is a result
                    failures.append(f"{fname}: {type(exc).__name__}")
                    continue
                if inspect(out, parse_header(out)).shown() == value:
                    ok += 1
                changed.append(changed_bytes(data, out))
            label = "sweepcast (exiftool)" if name == "sweepcast" and fmt == "png" else name
            rows.append({"format": fmt, "writer": label, "files": len(files), "per_file_bytes_changed": changed, "tag_reads_back": ok,
                         "failed": failures, "bytes_changed_median": float(np.median(changed)) if changed else None,
                         "bytes_changed_max": int(max(changed)) if changed else None,
                         "ms_per_file_median": float(np.median(times)) if times else None})
            print(rows[-1], flush=True)
    return {"rows": rows, "files": {k: [n for n, _ in v] for k, v in inputs.items()}}


def writers_markdown(result: dict) -> str:
    rows = [[r["format"], r["writer"], f"{r['tag_reads_back']}/{r['files']}", len(r["failed"]),
             r["bytes_changed_median"], r["bytes_changed_max"], r["ms_per_file_median"]] for r in result["rows"]]
    return "\n".join([
        "Orientation writers on the real JPEG/TIFF/PNG files of `exif/` and `orientation/formats/` plus generated "
        "untagged TIFFs (LE/BE, 1 and 3 pages, 400x300). Bytes changed: differing bytes when the length is kept, "
        "else the changed span before plus after, or for data appended at the end the bytes changed in place plus "
        "the appended ones (a tag patched in place changes 1-2 bytes). Our PNG writer is ExifTool (with an eXIf "
        "chunk added when a PNG keeps its EXIF only in ImageMagick's text chunk); an eXIf chunk found after IDAT "
        "is moved before it, which the span counts as a change of everything between.", "",
        md_table(["format", "writer", "tag reads back", "failed", "bytes changed (median)", "bytes changed (max)",
                  "ms per file (median)"], rows)])


def main() -> int:
    parser = argparse.ArgumentParser(prog=prog(), description=__doc__.splitlines()[0])
    parser.add_argument("--writers", action="store_true",
                        help="only the writers comparison (ours vs Exiv2 vs ExifTool), section orientation_writers")
    parser.add_argument("--throughput", action="store_true",
                        help="only: 12 MP photos/s, engine vs HTTP at 4 and 50 clients with /healthz latency "
                             "(section orientation_throughput)")
    parser.add_argument("--face-sizes", action="store_true",
                        help="only the Haar scans on faces of every size (section orientation_face_sizes)")
    parser.add_argument("--quick", action="store_true", help="a third of the photos, fewer speed repeats")
    parser.add_argument("--no-http", action="store_true", help="skip the end-to-end HTTP measurement")
    parser.add_argument("--no-speed", action="store_true", help="accuracy only")
    parser.add_argument("--clients", type=int, default=4, help="concurrent HTTP clients (default 4)")
    parser.add_argument("--text-section", action="store_true",
                        help="only what each photo costs and what is decided, by class (faces, text, neither), beside "
                             "the previous release: section orientation_text (benchmarks/_orientation_cost.py; about "
                             "25 minutes on 2 cores)")
    parser.add_argument("--previous-turns", type=int, choices=(1, 4), default=1,
                        help="with --text-section: the previous release reads the no-text images at 1 turn (90 "
                             "degrees; default: it costs seconds a photo) or at all 4")
    args = parser.parse_args()

    if args.throughput:
        faces = dataset("faces", "dev")
        yunet_model = data_root().parent / "models" / "yunet" / "face_detection_yunet_2023mar.onnx"
        return run_throughput(find_photos(faces), yunet_model if yunet_model.is_file() else None,
                              2 if args.quick else 4)
    if args.face_sizes:
        faces = dataset("faces", "dev")
        yunet_model = data_root().parent / "models" / "yunet" / "face_detection_yunet_2023mar.onnx"
        if faces is None or not yunet_model.is_file():
            print("skipped: the face-size set needs $SWEEPCAST_DATA/faces/dev and the YuNet model beside the data")
            return 0
        photos = find_photos(faces)
        result = run_face_sizes(photos[::3] if args.quick else photos, yunet_model)
        publish("orientation_face_sizes", result, face_sizes_markdown(result))
        return 0
    if args.writers:
        result = run_writers(args.quick)
        publish("orientation_writers", result, writers_markdown(result))
        return 0
    faces_dir = dataset("faces", "dev")
    if faces_dir is None:
        print(f"skipped: no face photos at {data_root() / 'faces' / 'dev'} (set SWEEPCAST_DATA)")
        return 0
    models = data_root().parent / "models"
    yunet = models / "yunet" / "face_detection_yunet_2023mar.onnx"
    mcs = models / "haar_mcs"
    yunet = yunet if yunet.is_file() else None
    mcs = mcs if (mcs / "haarcascade_mcs_nose.xml").is_file() else None
    if yunet is None:
        print("note: no YuNet model beside the data; yunet and combined are not measured")

    photos = find_photos(faces_dir)
    if args.quick:
        photos = [p for i, p in enumerate(photos) if i % 3 == 0 or p.name in NEGATIVES]
    if args.text_section:
        from benchmarks._orientation_cost import measure

        load_before = os.getloadavg()[0]
        results, text = measure(args, yunet)
        results["load_average"] = [load_before, os.getloadavg()[0]]
        publish("orientation_text", results, text + "\n\n" + load_note(load_before, os.getloadavg()[0]))
        return 0
    detectors = {name: get_detector(cfg) for name, cfg in configurations(yunet, mcs).items()}
    tallies = run_accuracy(photos, detectors)
    print(f"--- the same photos upscaled to ~{MEGAPIXELS:.0f} MP (the speed test's size)", flush=True)
    big_detectors = {n: d for n, d in detectors.items() if n in ("paper", "combined")}
    big_tallies = run_accuracy(photos, big_detectors, MEGAPIXELS)
    negatives = sum(p.name in NEGATIVES for p in photos)
    results: dict = {
        "dataset": {"photos": len(photos), "faces": len(photos) - negatives, "negatives": negatives,
                    "rotations": list(ROTATIONS), "jpeg_quality": 95},
        "configs": {name: t.summary() for name, t in tallies.items()},
        "configs_12mp": {name: t.summary() for name, t in big_tallies.items()},
        "paper_table3": PAPER,
        "default_config": "combined" if yunet is not None else "paper",
        "photos_per_s": None,
    }
    if not args.no_speed:
        repeats = 2 if args.quick else 5
        large = make_large_jpegs(photos, 6 if args.quick else 12)
        speed_detectors = {n: d for n, d in detectors.items() if n in ("paper", "combined")}
        speed: dict = {"photos": len(large), "repeats": repeats, "megapixels": MEGAPIXELS,
                       "mean_megabytes": float(np.mean([len(b) for b in large]) / 1e6),
                       "engine": run_engine_speed(large, speed_detectors, repeats), "http": {}}
        if not args.no_http:
            servers = {"paper": None} | ({"combined": yunet} if yunet is not None else {})
            for name, model in servers.items():
                speed["http"][name] = run_http_speed(large, model, args.clients, repeats)
                print(f"http {name}: {speed['http'][name]}", flush=True)
        results["speed"] = speed
        default_http = speed["http"].get(results["default_config"], {})
        results["photos_per_s"] = default_http.get("photos_per_s")
    for name, c in [*results["configs"].items(), *((f"{n}@12MP", c) for n, c in results["configs_12mp"].items())]:
        print(f"{name:10s} success {c['success_rate']:.3f} reject {c['reject_rate']:.3f} wrong {c['wrong']} "
              f"negatives decided {c['negative_decided']}/{c['negative_trials']}")
    publish("orientation", results, markdown(results))
    return 0


if __name__ == "__main__":
    with exit_on_sigterm():  # SIGTERM unwinds the serve_app block, which stops the server and its Ray
        sys.exit(main())
