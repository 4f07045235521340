"""Orientation over a whole photo library (issue 54): photos per second through ``sweepcast orient`` and the batch route.

The library: ``--photos`` photos (default 200) in the mix of a real library: 60 % with neither faces nor text (the
no-text set, :mod:`benchmarks._notext`), 30 % with faces (``$SWEEPCAST_DATA/faces/dev``, the dog left out), 10 % text
photos and scans (``$SWEEPCAST_DATA/orientation/text``); each scaled to about 12 megapixels, turned 90 degrees (so the
engine must turn it back 90 degrees clockwise: EXIF 6) and saved as a camera saves it: a JPEG of quality 92 with an
EXIF block (make, model, date, Orientation 1: the camera did not know). A source used twice is mirrored the second
time. The classes are interleaved, so the first photos of the library keep the mix. Built once into ``--library-dir``
(default: a folder in the system's temporary folder) and reused.

Sections (``--only``):

- ``cli``: ``python -m app orient LIBRARY --jobs 1`` then ``--jobs 2`` (a dry run from a fresh state: every photo
  analysed), then the ``--jobs 2`` run again as the next night's run would (every photo already decided: resumed).
  Photos per second over the whole command (start-up included), CPU per photo of the command with its processes, and
  of the whole machine over the run; decisions per class (right = turned back 90 degrees, wrong = any other turn).
- ``http``: the service (``python -m app serve``, its own local Ray on every core, the YuNet model and the text cue
  on: the default deployment) and a client that uploads the library as an organiser would: ``POST
  /v1/photos/batches`` of ``--batch`` photos (default 50), ``--in-flight`` uploads at once (default 2), each batch
  followed to its end. Photos per second from the first upload to the last batch's success; CPU per photo of the
  server's processes and of the whole machine.
- ``previous``: the release before this work (commit ``PREVIOUS``, exported with ``git archive`` and run with this
  environment's packages) through its CLI (one process: it had no other) and its batch route (two batches uploaded
  one after the other; it ran each batch as one task), and this code the same way, on the first
  ``--previous-photos`` photos (default 40; at its speed a larger share of the library takes the previous release
  many minutes).
- ``blocks``: what sizes the batch job's blocks (:mod:`workers.orientation.blocks`): the cost of a Ray task and of a
  block's record in the blob store, against the CPU of the photos themselves (a sample of each class analysed here),
  and the detector's build in a fresh process (paid once per worker process, not per block).

Run on a quiet machine from the repository root: ``python -m benchmarks.orientation_library`` (``--quick``: 20 photos,
10 of them for ``previous``, to try it).
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import cv2
import numpy as np
import piexif

from benchmarks._notext import no_text_images
from harness.proc import cpu_seconds, machine_busy_seconds, tree_cpu_seconds
from benchmarks._report import Sections, md_table
from benchmarks._timing import settle_server
from harness.servers import exit_on_sigterm, serve_app
from workers.common.datasets import data_root, dataset
from workers.orientation.geometry import rotate_view

ROOT = Path(__file__).resolve().parents[1]
PREVIOUS = "0874f9e"
"""The main branch before issue 54 (the engine one photo at a time, the batch job in one task)."""
MIX = (("neither", 0.6), ("faces", 0.3), ("text", 0.1))
MEGAPIXELS = 12.0
QUALITY = 92
TURN = 90
"""Clockwise degrees that show each stored photo upright (what the engine must find)."""
LIBRARY_VERSION = 2
"""Part of the cached library's manifest: a change in how photos are made builds the library again (so does another
set of sources: a library built before the no-text set's Debian packages were installed is not reused after)."""
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".webp")

sections = Sections("orientation_library", __doc__)
sections.parser.add_argument("--photos", type=int, default=200, help="photos in the library (default 200)")
sections.parser.add_argument("--batch", type=int, default=50, help="photos per uploaded batch (default 50)")
sections.parser.add_argument("--in-flight", type=int, default=2, help="batches uploaded at once (default 2)")
sections.parser.add_argument("--previous-photos", type=int, default=40,
                             help="photos of the library the previous release analyses (default 40)")
sections.parser.add_argument("--library-dir", type=Path, default=None,
                             help="where the library is built and kept (default: sweepcast-bench-library-N in the "
                                  "system's temporary folder)")
sections.parser.add_argument("--quick", action="store_true", help="20 photos, 10 for the previous release")


# ---- the library ---------------------------------------------------------------------------------------------------

def _sources() -> dict[str, list[tuple[str, Callable[[], np.ndarray]]]]:
    """(name, load BGR) of each class's source images, in a fixed order."""
    faces = dataset("faces", "dev")
    text = dataset("orientation", "text")
    if faces is None or text is None:
        raise SystemExit(f"needs $SWEEPCAST_DATA/faces/dev and orientation/text (looked in {data_root()})")

    def files(folder: Path, leave_out: set[str]) -> list[tuple[str, Callable[[], np.ndarray]]]:
        found = sorted(p for p in folder.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES and p.name not in leave_out)
        return [(p.stem, lambda p=p: cv2.imread(str(p), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION))
                for p in found]

    return {"neither": [(f"{category.replace(' ', '_')}-{Path(name).stem}", load)
                        for category, name, load in no_text_images(data_root())],
            "faces": files(faces, {"dogs.jpg"}), "text": files(text, set())}


def _classes(count: int) -> list[str]:
    """The class of each photo: the mix's shares, interleaved so that every prefix keeps about the mix."""
    counts = {name: round(share * count) for name, share in MIX[1:]}
    counts[MIX[0][0]] = count - sum(counts.values())
    slots = [((k + 0.5) / n, name) for name, n in counts.items() for k in range(n)]
    return [name for _, name in sorted(slots)]


def _camera_jpeg(upright: np.ndarray) -> bytes:
    """``upright`` at about 12 MP, turned so that a 90-degree clockwise turn shows it upright, as a camera's JPEG."""
    scale = (MEGAPIXELS * 1e6 / (upright.shape[0] * upright.shape[1])) ** 0.5
    size = (round(upright.shape[1] * scale), round(upright.shape[0] * scale))
    image = cv2.resize(upright, size, interpolation=cv2.INTER_CUBIC if scale > 1 else cv2.INTER_AREA)
    stored = rotate_view(image, (360 - TURN) % 360)
    ok, buf = cv2.imencode(".jpg", stored, [cv2.IMWRITE_JPEG_QUALITY, QUALITY])
    assert ok
    exif = piexif.dump({"0th": {piexif.ImageIFD.Make: b"Bench", piexif.ImageIFD.Model: b"Camera 12",
                                piexif.ImageIFD.Orientation: 1},
                        "Exif": {piexif.ExifIFD.DateTimeOriginal: b"2026:06:01 12:00:00"}})
    out = io.BytesIO()
    piexif.insert(exif, buf.tobytes(), out)
    return out.getvalue()


def build_library(count: int, folder: Path) -> list[dict[str, str]]:
    """The library's photos (``{"file", "class", "source"}``), made into ``folder`` unless already there."""
    manifest_path = folder / "manifest.json"
    sources = _sources()
    used = {name: 0 for name in sources}
    plan = []  # (class, source name, its loader, a mirror image)
    for cls in _classes(count):
        k = used[cls]
        used[cls] += 1
        name, load = sources[cls][k % len(sources[cls])]
        plan.append((cls, name, load, bool((k // len(sources[cls])) % 2)))
    if manifest_path.exists():
        manifest = json.loads(manifest_path.read_text())
        if manifest.get("version") == LIBRARY_VERSION \
                and [(p["class"], p["source"]) for p in manifest["photos"]] == [(c, n) for c, n, _, _ in plan] \
                and all((folder / "photos" / p["file"]).is_file() for p in manifest["photos"]):
            return manifest["photos"]
    shutil.rmtree(folder, ignore_errors=True)
    (folder / "photos").mkdir(parents=True)
    photos = []
    start = time.perf_counter()
    for i, (cls, name, load, mirrored) in enumerate(plan):
        image = load()
        if mirrored:  # second time round: the mirror image
            image = cv2.flip(image, 1)
        file = f"{i:05d}-{cls}-{name[:60]}.jpg".replace(" ", "_").replace("/", "_")
        (folder / "photos" / file).write_bytes(_camera_jpeg(image))
        photos.append({"file": file, "class": cls, "source": name})
        print(f"library: {i + 1}/{count} {file}", file=sys.stderr, flush=True)
    manifest_path.write_text(json.dumps({"version": LIBRARY_VERSION, "photos": photos}, indent=1))
    print(f"library: built in {time.perf_counter() - start:.0f} s", file=sys.stderr)
    return photos


def _library(args: argparse.Namespace) -> tuple[Path, list[dict[str, str]]]:
    count = 20 if args.quick else args.photos
    folder = args.library_dir or Path(tempfile.gettempdir()) / f"sweepcast-bench-library-{count}"
    return folder / "photos", build_library(count, folder)


def _subset(photos_dir: Path, photos: list[dict[str, str]], count: int, into: Path) -> Path:
    """A folder holding (hard links to) the first ``count`` photos."""
    into.mkdir(parents=True, exist_ok=True)
    for p in photos[:count]:
        with contextlib.suppress(FileExistsError):
            os.link(photos_dir / p["file"], into / p["file"])
    return into


def _yunet() -> Path | None:
    model = data_root().parent / "models" / "yunet" / "face_detection_yunet_2023mar.onnx"
    return model if model.is_file() else None


def _mix_text(photos: list[dict[str, str]]) -> str:
    counts = {name: sum(p["class"] == name for p in photos) for name, _ in MIX}
    return ", ".join(f"{n} {name}" for name, n in counts.items())


# ---- decisions --------------------------------------------------------------------------------------------------------

def _tally(rows: list[tuple[str, Any]]) -> dict[str, dict[str, int]]:
    """Per class: photos decided right (turned back 90 degrees), wrong (another turn), rejected, errors; ``rows`` is
    (file name, rotation decided or None, or "error")."""
    out: dict[str, dict[str, int]] = {name: {"right": 0, "wrong": 0, "rejected": 0, "errors": 0} for name, _ in MIX}
    for name, rotation in rows:
        cls = name.split("-")[1]
        key = "errors" if rotation == "error" else "rejected" if rotation is None else (
            "right" if rotation == TURN else "wrong")
        out[cls][key] += 1
    return out


def _tally_text(tally: dict[str, dict[str, int]]) -> str:
    return "; ".join(f"{cls} {t['right']} right, {t['wrong']} wrong, {t['rejected']} rejected"
                     + (f", {t['errors']} errors" if t["errors"] else "") for cls, t in tally.items())


# ---- the CLI ---------------------------------------------------------------------------------------------------------

def run_cli(folder: Path, jobs: int | None, work: Path, *, cwd: Path = ROOT, resume: bool = False,
            yunet: Path | None = None) -> dict[str, Any]:
    """``python -m app orient folder`` (from ``cwd``: another release's code there), timed: photos/s, the CPU of the
    command with every process it waited for, the machine's busy CPU, the decisions. ``jobs`` None: a release without
    ``--jobs`` (and without a state file)."""
    report = work / "report"
    cmd = [sys.executable, "-m", "app", "orient", str(folder), "--report", str(report)]
    if yunet is not None:
        cmd += ["--yunet", str(yunet)]
    if jobs is not None:
        cmd += ["--jobs", str(jobs), "--state", str(work / "state.jsonl")] + ([] if resume else ["--no-resume"])
    env = {**os.environ, "PYTHONPATH": str(cwd)}
    children0, busy0, start = resource.getrusage(resource.RUSAGE_CHILDREN), machine_busy_seconds(), time.perf_counter()
    done, results_at = _run_timed(cmd, cwd, env)
    wall = time.perf_counter() - start
    busy = machine_busy_seconds() - busy0
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (children.ru_utime - children0.ru_utime) + (children.ru_stime - children0.ru_stime)
    if done.returncode not in (0, 2):  # 2: some file could not be read (reported per photo)
        raise RuntimeError(f"{' '.join(cmd)} exited {done.returncode}: {done.stderr[-2000:]}")
    rows = json.loads(report.with_name("report.json").read_text())
    count = len(rows)
    first, last = (results_at[0] - start, results_at[-1] - start) if len(results_at) > 1 else (wall, wall)
    return {"command": " ".join(cmd[1:]), "photos": count, "wall_s": wall, "photos_per_s": count / wall,
            "first_result_s": first,
            "photos_per_s_started": (len(results_at) - 1) / (last - first) if last > first else None,
            "cpu_ms_per_photo": 1000 * cpu / count, "machine_busy_ms_per_photo": 1000 * busy / count,
            "decisions": _tally([(Path(r["path"]).name, "error" if r["error"] else r["rotation_degrees"])
                                 for r in rows])}


def _run_timed(cmd: list[str], cwd: Path, env: dict[str, str]) -> tuple[subprocess.CompletedProcess, list[float]]:
    """Run ``cmd``; also the time (``perf_counter``) each progress line on its stderr came (one line a photo: the
    command's ``ProgressBar`` writes plain lines when stderr is not a terminal)."""
    at, lines = [], []
    with subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) as proc:
        for line in proc.stderr:
            lines.append(line)
            if re.match(r"orient +\d", line):
                at.append(time.perf_counter())
    return subprocess.CompletedProcess(cmd, proc.returncode, None, "".join(lines)), at


def bench_cli(args: argparse.Namespace) -> tuple[dict[str, Any], str]:
    photos_dir, photos = _library(args)
    yunet = _yunet()
    with tempfile.TemporaryDirectory(prefix="sweepcast-bench-cli-") as tmp:
        one = run_cli(photos_dir, 1, Path(tmp) / "one", yunet=yunet)
        two = run_cli(photos_dir, 2, Path(tmp) / "two", yunet=yunet)
        again = run_cli(photos_dir, 2, Path(tmp) / "two", resume=True, yunet=yunet)
    out = {"photos": len(photos), "jobs_1": one, "jobs_2": two, "jobs_2_resumed": again}
    rows = [[label, r["photos_per_s"], r["wall_s"], r["first_result_s"], r["photos_per_s_started"],
             r["cpu_ms_per_photo"], r["machine_busy_ms_per_photo"]]
            for label, r in (("`--jobs 1`", one), ("`--jobs 2`", two), ("`--jobs 2` again (every photo resumed)",
                                                                         again))]
    md = (f"### The CLI\n\n`sweepcast orient` over the library ({len(photos)} photos: {_mix_text(photos)}), a dry run "
          f"from a fresh state, then again as the next run would (YuNet {'on' if yunet else 'not installed'}, the text "
          "cue on). CPU: the command and every process it waited for (with `--jobs 2` its helpers are forked by a fork "
          "server it does not wait for, so this column leaves them out: read the machine's); machine: every core's busy "
          "time over the run, on a machine otherwise idle. First result: seconds from the command's start to its "
          "first photo's result (its start-up: Python, the helpers, their detectors); photos/s once started: the "
          "photos after the first over the time from the first result to the last, the rate a library of thousands "
          "runs at.\n\n"
          + md_table(["run", "photos/s", "wall s", "first result s", "photos/s once started", "CPU ms/photo",
                      "machine busy ms/photo"], rows)
          + f"\n\nDecisions (`--jobs 2`): {_tally_text(two['decisions'])}. `--jobs 1` decided the same: "
            f"{one['decisions'] == two['decisions']}.\n")
    return out, md


# ---- the service ----------------------------------------------------------------------------------------------------

@contextlib.contextmanager
def served(cwd: Path, tmp: Path, yunet: Path | None, **env: str) -> Iterator[Any]:
    """The service from ``cwd``'s code (its own local Ray, every core; ``env``: more settings), settled after its
    start (``app.settled``: what that took, :func:`settle_server`)."""
    tmp.mkdir(parents=True, exist_ok=True)
    env = {"SWEEPCAST_DATA_DIR": str(tmp / "data"), "SWEEPCAST_ORIENTATION_YUNET_MODEL": str(yunet) if yunet else None,
           "SWEEPCAST_DEMO_RIG": "false", "SWEEPCAST_WARM_KERNELS": "false", "PYTHONPATH": str(cwd), **env}
    with serve_app(env, log=tmp / "server.log", cwd=cwd) as app:
        app.settled = settle_server(app.base, app.proc.pid, tree_cpu_seconds, interval_s=1.0, timeout_s=300.0)
        yield app


def upload_library(base: str, pid: int, files: list[Path], batch: int, in_flight: int) -> dict[str, Any]:
    """POST ``files`` in batches of ``batch``, ``in_flight`` at once, each followed to its end; timed."""
    import httpx

    batches = [files[i:i + batch] for i in range(0, len(files), batch)]
    jobs: list[dict[str, Any]] = [{} for _ in batches]
    pending = iter(range(len(batches)))
    lock = threading.Lock()

    def client() -> None:
        with httpx.Client(base_url=base, timeout=600.0) as http:
            while True:
                with lock:
                    k = next(pending, None)
                if k is None:
                    return
                t0 = time.perf_counter()
                body = [("files", (p.name, p.read_bytes(), "image/jpeg")) for p in batches[k]]
                job = http.post("/v1/photos/batches", files=body).raise_for_status().json()
                uploaded = time.perf_counter() - t0
                while (job := http.get(f"/v1/jobs/{job['id']}").json())["state"] not in ("succeeded", "failed",
                                                                                         "cancelled"):
                    time.sleep(0.2)
                entries = (http.get(f"/v1/jobs/{job['id']}/results/report.json").json()
                           if job["state"] == "succeeded" else [])
                jobs[k] = {"id": job["id"], "state": job["state"], "error": job["error"], "upload_s": uploaded,
                           "batch_s": time.perf_counter() - t0, "entries": entries}

    cpu0, busy0, start = tree_cpu_seconds(pid, reaped=True), machine_busy_seconds(), time.perf_counter()
    threads = [threading.Thread(target=client) for _ in range(min(in_flight, len(batches)))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    wall = time.perf_counter() - start
    cpu, busy = tree_cpu_seconds(pid, reaped=True) - cpu0, machine_busy_seconds() - busy0
    failed = [j for j in jobs if j.get("state") != "succeeded"]
    if failed:
        raise RuntimeError(f"{len(failed)} batches did not succeed: {failed[0].get('error')}")
    entries = [e for j in jobs for e in j["entries"]]
    return {"photos": len(files), "batches": len(batches), "batch": batch, "in_flight": in_flight, "wall_s": wall,
            "photos_per_s": len(files) / wall, "server_cpu_ms_per_photo": 1000 * cpu / len(files),
            "machine_busy_ms_per_photo": 1000 * busy / len(files),
            "median_upload_s": statistics.median(j["upload_s"] for j in jobs),
            "median_batch_s": statistics.median(j["batch_s"] for j in jobs), "job_ids": [j["id"] for j in jobs],
            "decisions": _tally([(e["filename"], "error" if e["error"] else e["report"]["rotation_degrees"])
                                 for e in entries])}


def bench_http(args: argparse.Namespace) -> tuple[dict[str, Any], str]:
    photos_dir, photos = _library(args)
    yunet = _yunet()
    files = [photos_dir / p["file"] for p in photos]
    batch = _batch(args, len(files))
    with tempfile.TemporaryDirectory(prefix="sweepcast-bench-http-") as tmp, served(ROOT, Path(tmp), yunet) as app:
        out = upload_library(app.base, app.proc.pid, files, batch, args.in_flight)
        out["start"] = app.settled
        out["next"] = upload_library(app.base, app.proc.pid, files, batch, args.in_flight)
        out["review"] = review_thumbnails(app.base, app.proc.pid, out["next"]["job_ids"][0])
    with tempfile.TemporaryDirectory(prefix="sweepcast-bench-http-") as tmp, \
            served(ROOT, Path(tmp), yunet, SWEEPCAST_WARM_WORKERS="false") as app:
        out["cold"] = upload_library(app.base, app.proc.pid, files, batch, args.in_flight)
        out["cold"]["start"] = app.settled
    review = out["review"]
    rows = [[label, r["photos_per_s"], r["wall_s"], r["server_cpu_ms_per_photo"], r["machine_busy_ms_per_photo"],
             r["median_upload_s"], r["median_batch_s"], r["start"]["server_tree_cpu_s"] if "start" in r else ""]
            for label, r in (("first, after the service's start", out), ("the next, on the same service", out["next"]),
                             ("first, workers not made ready at the start (`SWEEPCAST_WARM_WORKERS=false`)",
                              out["cold"]))]
    md = (f"### The batch route\n\nThe service (its local Ray on every core; YuNet {'on' if yunet else 'not installed'}, "
          f"the text cue on) and one client uploading the library ({len(photos)} photos) as `POST "
          f"/v1/photos/batches` of {out['batch']} photos, {out['in_flight']} uploads at once, each batch followed to "
          "its end, once the service has settled after its start (its Ray workers made ready for batch jobs: "
          "`SWEEPCAST_WARM_WORKERS`, the default); then the same library again, as the next library a running "
          "service gets; then the first library of a service started without that warm-up, as earlier releases "
          "started. CPU: the server's processes (its Ray workers included, those ended meanwhile too); machine: every "
          "core's busy time (the client's included: it runs on the same cores); start-up CPU: the server's processes "
          "from its start until it settled, before the library.\n\n"
          + md_table(["library", "photos/s", "wall s", "server CPU ms/photo", "machine busy ms/photo",
                      "median upload s", "median batch s (upload to done)", "start-up CPU s"], rows)
          + f"\n\nDecisions: {_tally_text(out['decisions'])}; the next library's the same: "
            f"{out['next']['decisions'] == out['decisions']}; without the warm-up: "
            f"{out['cold']['decisions'] == out['decisions']}.\n\n"
            f"The review page of that library's first batch: its {review['thumbnails']} photos left for a person, each "
            f"thumbnail made when the page asks for it: {review['server_cpu_ms_per_thumbnail']:.1f} ms of the "
            f"service's CPU each, {review['median_ms']:.0f} ms from request to answer (median, one at a time).\n")
    return out, md


def review_thumbnails(base: str, pid: int, job_id: str) -> dict[str, Any]:
    """Every thumbnail of batch ``job_id``'s review queue fetched in turn, as its review page asks for them. CPU: the
    server's own process, where they are made (its tree's total would drop as Ray ends the workers the library left
    idle meanwhile)."""
    import httpx

    with httpx.Client(base_url=base, timeout=60.0) as http:
        items = http.get(f"/v1/photos/batches/{job_id}/review").raise_for_status().json()["items"]
        times = []
        cpu0 = cpu_seconds(pid)
        for item in items:
            t0 = time.perf_counter()
            http.get(item["thumbnail"]).raise_for_status()
            times.append(1000 * (time.perf_counter() - t0))
        cpu = cpu_seconds(pid) - cpu0
    return {"thumbnails": len(items), "server_cpu_ms_per_thumbnail": 1000 * cpu / max(1, len(items)),
            "median_ms": statistics.median(times) if times else 0.0}


def _batch(args: argparse.Namespace, photos: int) -> int:
    """Photos per batch: ``--batch``, fewer for a small library so that every upload slot gets two batches."""
    return max(1, min(args.batch, photos // (2 * args.in_flight)))


# ---- the previous release ---------------------------------------------------------------------------------------

def bench_previous(args: argparse.Namespace) -> tuple[dict[str, Any], str]:
    photos_dir, photos = _library(args)
    count = min(10 if args.quick else args.previous_photos, len(photos))
    yunet = _yunet()
    with tempfile.TemporaryDirectory(prefix="sweepcast-bench-previous-") as name:
        tmp = Path(name)
        previous = tmp / "previous"
        previous.mkdir()
        subprocess.run(f"git archive {PREVIOUS} | tar -x -C {previous}", shell=True, cwd=ROOT, check=True)
        subset = _subset(photos_dir, photos, count, tmp / "subset")
        files = sorted(subset.iterdir())
        batch = max(1, count // 2)  # two batches, one at a time: the previous release's job used one core each
        out: dict[str, Any] = {"commit": PREVIOUS, "photos": count, "batch": batch}
        out["previous_cli"] = run_cli(subset, None, tmp / "p-cli", cwd=previous, yunet=yunet)
        out["cli_jobs_1"] = run_cli(subset, 1, tmp / "c-cli1", yunet=yunet)
        out["cli_jobs_2"] = run_cli(subset, 2, tmp / "c-cli2", yunet=yunet)
        for label, cwd in (("previous_http", previous), ("http", ROOT)):
            with served(cwd, tmp / label, yunet) as app:
                out[label] = upload_library(app.base, app.proc.pid, files, batch, 1)
    rows = [[label, r["photos_per_s"], r.get("cpu_ms_per_photo", r.get("server_cpu_ms_per_photo")),
             r["machine_busy_ms_per_photo"], _tally_text({k: v for k, v in r["decisions"].items()
                                                          if sum(v.values())})]
            for label, r in ((f"{PREVIOUS} CLI (one process)", out["previous_cli"]),
                             ("this CLI `--jobs 1`", out["cli_jobs_1"]), ("this CLI `--jobs 2`", out["cli_jobs_2"]),
                             (f"{PREVIOUS} batch route", out["previous_http"]), ("this batch route", out["http"]))]
    ratio_cli = out["cli_jobs_2"]["photos_per_s"] / out["previous_cli"]["photos_per_s"]
    ratio_http = out["http"]["photos_per_s"] / out["previous_http"]["photos_per_s"]
    md = (f"### Against the previous release\n\nThe first {count} photos of the library ({_mix_text(photos[:count])}) "
          f"through the release before this work ({PREVIOUS}, run from an export of that commit with this "
          f"environment's packages) and through this code, in the same run. The batch route gets two batches of "
          f"{batch} photos, one after the other, as an organiser that uploads one batch at a time sends them (the "
          "previous release ran each batch as one task on one core; with two uploads at once it too kept two cores "
          "busy).\n\n"
          + md_table(["path", "photos/s", "CPU ms/photo (command or server)", "machine busy ms/photo", "decisions"],
                     rows)
          + f"\n\nThis code over the previous release: CLI {ratio_cli:.1f}x (`--jobs 2` against its one process), "
            f"batch route {ratio_http:.1f}x.\n")
    return out, md


# ---- block sizes ----------------------------------------------------------------------------------------------------

def _noop(task: int) -> int:
    return task


def _ray_task_ms() -> dict[str, float]:
    """Ray's cost per fanned-out task on a local cluster of 2 CPUs: 200 tasks through the job's fan-out
    (:class:`workers.fanout.OnRay`: one submitted per CPU, the next as one finishes), wall ms per task; and one task at
    a time, median ms from submit to result."""
    import ray

    from app import raycluster
    from workers.fanout import OnRay
    from workers.ray_tasks import run_block_task

    started = raycluster.connect(None, num_cpus=2)
    try:
        ray.get([run_block_task.remote(_noop, i) for i in range(40)])  # workers started and warm
        start = time.perf_counter()
        OnRay().map("noop", _noop, list(range(200)))
        batch_ms = 1000 * (time.perf_counter() - start) / 200
        single = []
        for i in range(50):
            t0 = time.perf_counter()
            ray.get(run_block_task.remote(_noop, i))
            single.append(1000 * (time.perf_counter() - t0))
        return {"ms_per_task_fanned_out": batch_ms, "ms_per_task_one_at_a_time": statistics.median(single)}
    finally:
        if started:
            ray.shutdown()


def _record_ms(entry: dict[str, Any]) -> float:
    """Median ms to write a block's record of 8 entries like ``entry`` to a blob store folder."""
    from workers.orientation.blocks import BLOCK_MAX_PHOTOS
    from workers.storage import DirectoryBlobStore
    from workers.workarea import WorkArea

    with tempfile.TemporaryDirectory() as tmp:
        work = WorkArea.for_job(DirectoryBlobStore(tmp), "j", {})
        record = json.dumps({"entries": [entry] * BLOCK_MAX_PHOTOS, "files": {}}).encode()
        times = []
        for i in range(30):
            t0 = time.perf_counter()
            work.put(f"blocks/{i:06d}.json", record)
            times.append(1000 * (time.perf_counter() - t0))
        return statistics.median(times)


def _detector_build_s(yunet: Path | None) -> float:
    """Seconds a fresh process takes to build the service's detector (after its imports), median of 3."""
    code = ("import sys, time; from workers.orientation.detect import DetectorConfig, get_detector; "
            "t = time.perf_counter(); get_detector(DetectorConfig(yunet_model=sys.argv[1] or None)); "
            "print(time.perf_counter() - t)")
    runs = [float(subprocess.run([sys.executable, "-c", code, str(yunet or "")], cwd=ROOT, capture_output=True,
                                 text=True, check=True).stdout.split()[-1]) for _ in range(3)]
    return statistics.median(runs)


def _photo_cpu_ms(photos_dir: Path, photos: list[dict[str, str]], per_class: int,
                  yunet: Path | None) -> tuple[dict[str, float], dict[str, Any]]:
    """Median CPU ms (this thread, OpenCV on one thread) of ``analyze`` per class on ``per_class`` photos of each,
    after a first photo of each class (untimed: a worker's first use of its readers); and one entry's report as a block
    records it."""
    from workers.orientation.detect import DetectorConfig, get_detector
    from workers.orientation.orient import analyze

    detector = get_detector(DetectorConfig(yunet_model=yunet))
    cv2.setNumThreads(1)
    for cls, _ in MIX:  # untimed: what a worker does once (Tesseract's and the recogniser's first use), not per photo
        first = next(p for p in photos if p["class"] == cls)
        analyze((photos_dir / first["file"]).read_bytes(), detector, filename=first["file"])
    out, entry = {}, {}
    for cls, _ in MIX:
        times = []
        for p in [p for p in photos if p["class"] == cls][1:per_class + 1]:
            data = (photos_dir / p["file"]).read_bytes()
            t0 = time.thread_time()
            report = analyze(data, detector, filename=p["file"])
            times.append(1000 * (time.thread_time() - t0))
            entry = {"index": 0, "input": "photo-0000", "filename": p["file"], "report": report.model_dump(mode="json"),
                     "error": None, "fixed_file": None, "note": None, "review": None}
        out[cls] = statistics.median(times)
    return out, entry


def bench_blocks(args: argparse.Namespace) -> tuple[dict[str, Any], str]:
    from workers.orientation.blocks import BLOCK_MAX_PHOTOS

    photos_dir, photos = _library(args)
    yunet = _yunet()
    per_class = 2 if args.quick else 12
    photo_ms, entry = _photo_cpu_ms(photos_dir, photos, per_class, yunet)
    mixed_ms = sum(share * photo_ms[cls] for cls, share in MIX)
    ray_ms = _ray_task_ms()
    record_ms = _record_ms(entry)
    build_s = _detector_build_s(yunet)
    per_block_ms = ray_ms["ms_per_task_fanned_out"] + record_ms
    sizes = (1, 2, 4, 8, 16)
    rows = [[b, per_block_ms / b, 100 * per_block_ms / b / mixed_ms, b * mixed_ms / 1000] for b in sizes]
    out = {"photo_cpu_ms_median": photo_ms, "mixed_cpu_ms_per_photo": mixed_ms, "ray": ray_ms,
           "record_write_ms": record_ms, "detector_build_s": build_s, "block_max_photos": BLOCK_MAX_PHOTOS,
           "table": [dict(zip(("block", "overhead_ms_per_photo", "overhead_percent", "block_s"), r)) for r in rows]}
    md = ("### Block sizes\n\nWhat a block costs beside its photos: a Ray task "
          f"({ray_ms['ms_per_task_fanned_out']:.1f} ms each through the job's fan-out, one per CPU submitted as one "
          f"finishes; {ray_ms['ms_per_task_one_at_a_time']:.1f} ms one at a time) and its record written to the blob "
          f"store ({record_ms:.2f} ms), against the photos' own CPU: median "
          + ", ".join(f"{cls} {ms:.0f} ms" for cls, ms in photo_ms.items())
          + f" ({per_class} of each after a first one untimed, OpenCV on one thread), {mixed_ms:.0f} ms for the library's mix. The detector is "
          f"built once per worker process ({build_s:.2f} s in a fresh one), not per block.\n\n"
          + md_table(["photos per block", "overhead ms/photo", "overhead % of the mix's CPU", "a block's CPU s"], rows)
          + f"\n\nThe job uses blocks of at most {BLOCK_MAX_PHOTOS} photos, at least 4 per CPU where the batch allows "
            "(`workers/orientation/blocks.py`).\n")
    return out, md


sections.add("cli", "sweepcast orient over the library: --jobs 1, --jobs 2, and again resumed", bench_cli)
sections.add("http", "the batch route: the library uploaded in batches to a served app", bench_http)
sections.add("previous", f"the release before this work ({PREVIOUS}) and this code on a share of the library",
             bench_previous)
sections.add("blocks", "what sizes the batch job's blocks: Ray's and the record's cost against the photos'", bench_blocks)


def markdown(results: dict[str, Any], kept: list[str]) -> str:
    head = ("Orientation over a whole library (issue 54): a mixed library of ~12 MP camera JPEGs, each turned 90 "
            "degrees (60 % neither faces nor text, 30 % faces, 10 % text), through `sweepcast orient` and the batch "
            "route (`python -m benchmarks.orientation_library`; how the library is made: its docstring). Goal: "
            ">= 15 photos/s on two cores.\n\n")
    return head + "\n".join(sections.stored_markdown(results, kept))


if __name__ == "__main__":
    with exit_on_sigterm():
        raise SystemExit(sections.main(markdown))
