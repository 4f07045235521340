"""The ``scale`` section of ``benchmarks/drone.py`` (issue 57): a synthetic nadir survey of 28, ~110, ~440 and
~1,000 stills (640x480) and a 12 MP variant of the smallest, each through the service (``python -m app serve``) on
a Ray cluster of one worker node and of two (``ray start``: a head without task CPUs plus worker nodes sharing this
machine's cores), every photo in the map.

Per run: wall (upload to the last result), the machine's busy CPU seconds meanwhile, each node's peak resident
memory (its raylet and every process under it, sampled twice a second) and CPU, the tasks each node ran, the map
against the truth (:func:`benchmarks._survey_eval.evaluate`: coverage of the photos' true footprints, DSM error,
orthophoto PSNR). Across runs: how cost grows with the number of stills (the exponent of wall and CPU from ~110 to
~1,000), how peak memory per node does, and whether the two-node run's products are the single node's.

The stills are rendered once into a cache folder (``--survey-cache``), so the runs of one size share them and a
second command does not render them again; each command runs the sizes and node counts it names and keeps the
others' figures from the previous results (``--scale-sizes``, ``--scale-nodes``).
"""
from __future__ import annotations

import json
import math
import os
import re
import shutil
import tempfile
import threading
import time
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from harness.proc import cpu_seconds, descendants, machine_busy_seconds, status_mb
from benchmarks._report import md_table
from benchmarks._survey_eval import ALTITUDE, evaluate, photos_for, survey, survey_cameras

SIZES: dict[str, tuple[tuple[float, float], tuple[int, int]]] = {
    "28": ((80.0, 60.0), (640, 480)),
    "110": ((230.0, 160.0), (640, 480)),
    "440": ((480.0, 370.0), (640, 480)),
    "1000": ((730.0, 570.0), (640, 480)),
    "28@12mp": ((80.0, 60.0), (4000, 3000)),
    "28+lens": ((80.0, 60.0), (640, 480)),
    "28@12mp+lens": ((80.0, 60.0), (4000, 3000)),
}
"""Size name -> (area in metres, still size): lawnmower surveys at 60 m, 75 % forward and 65 % side overlap."""
LENS_GIVEN = {"28+lens", "28@12mp+lens"}
"""Runs whose job is given the true lens (focal length, principal point, distortion) as parameters, the rest none: what
the map is once the one thing a nadir survey's images cannot tell, the focal length, is known (a calibrated camera,
ground control). Not counted in the goals "at every size", which are for a job without parameters."""
GOALS = {"coverage": 0.99, "dsm_gsd": 1.0, "ortho_db": 30.0, "exponent": 1.1, "rss_growth": 1.5}
JOB_TIMEOUT_S = 6 * 3600
SAMPLE_S = 0.5


def default_cache() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "sweepcast" / "surveys"


def _zip(folder: Path) -> Path:
    """The survey's stills as one zip beside its folder (stored: JPEGs do not compress), made once."""
    path = folder.with_suffix(".zip")
    if not path.exists():
        tmp = path.with_suffix(".zip.part")
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as zf:
            for p in sorted(folder.glob("*.jpg")):
                zf.write(p, f"survey/{p.name}")
        tmp.replace(path)
    return path


class NodeSampler:
    """Each Ray node's memory and CPU while a job runs: every raylet of the cluster at ``gcs_address`` and every
    process under it, sampled in a thread (peak of the summed resident memory, CPU seconds of every process
    seen)."""

    def __init__(self, gcs_address: str) -> None:
        self.port = gcs_address.rsplit(":", 1)[1]
        self.peak_mb: dict[str, float] = {}
        self.cpu: dict[str, dict[int, float]] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _raylets(self) -> dict[str, int]:
        out = {}
        for entry in os.scandir("/proc"):
            if not entry.name.isdigit():
                continue
            try:
                args = Path(f"/proc/{entry.name}/cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if not args or not args[0].endswith(b"/raylet"):
                continue
            text = [a.decode(errors="replace") for a in args]
            if any(a.endswith(f":{self.port}") and "gcs" in a for a in text):
                node = next((a.split("=", 1)[1] for a in text if a.startswith("--node_id=")), entry.name)
                out[node] = int(entry.name)
        return out

    def _run(self) -> None:
        while not self._stop.is_set():
            for node, raylet in self._raylets().items():
                pids = descendants(raylet)
                rss = sum(v for v in (status_mb(p, "VmRSS") for p in pids) if not math.isnan(v))
                self.peak_mb[node] = max(self.peak_mb.get(node, 0.0), rss)
                seen = self.cpu.setdefault(node, {})
                for p in pids:
                    c = cpu_seconds(p)
                    if not math.isnan(c):
                        seen[p] = max(seen.get(p, 0.0), c)
            self._stop.wait(SAMPLE_S)

    def __enter__(self) -> "NodeSampler":
        self._baseline = {n: {p: cpu_seconds(p) for p in descendants(r)} for n, r in self._raylets().items()}
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()

    def cpu_seconds(self) -> dict[str, float]:
        """CPU seconds each node's processes spent since the sampler started."""
        out = {}
        for node, seen in self.cpu.items():
            base = self._baseline.get(node, {})
            out[node] = sum(c - (base.get(p, 0.0) if not math.isnan(base.get(p, 0.0)) else 0.0) for p, c in seen.items())
        return out


def _wait(client, job_id: str) -> dict[str, Any]:
    deadline = time.monotonic() + JOB_TIMEOUT_S
    while True:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if job["state"] in ("succeeded", "failed", "cancelled"):
            return job
        if time.monotonic() > deadline:
            raise RuntimeError(f"job {job_id} did not finish in {JOB_TIMEOUT_S} s: {job}")
        time.sleep(1.0)


def _submit(client, zip_path: Path, params: dict[str, Any] | None = None) -> str:
    with open(zip_path, "rb") as f:
        r = client.post("/v1/reconstructions", files={"media": (zip_path.name, f, "application/zip")},
                        data={"params": json.dumps(params)} if params else None, timeout=600)
    if r.status_code != 202:
        raise RuntimeError(f"upload refused: {r.status_code} {r.text[:500]}")
    return r.json()["id"]


def run_one(size: str, nodes: int, cache: Path, cpus: int) -> dict[str, Any]:
    """One survey through the service on a cluster of ``nodes`` worker nodes of ``cpus / nodes`` CPUs each."""
    import httpx

    from harness.surveys import small_survey
    from harness.servers import ray_cluster, serve_app

    area, size_px = SIZES[size]
    # 12 MP stills at one ray a pixel: the ground's finest texture (0.25 m) spans 12 of their pixels, nothing aliases
    sv = survey(area, size_px, cache, supersample=3 if size_px[0] <= 640 else 1)
    zip_path = _zip(sv.folder)
    out: dict[str, Any] = {"photos": len(sv.cameras), "still_size": list(size_px), "area_m": list(area),
                           "nodes": nodes, "cpus_per_node": max(1, cpus // nodes), "render_s": round(sv.render_s, 1),
                           "upload_mb": round(zip_path.stat().st_size / 2**20, 1)}
    with tempfile.TemporaryDirectory(prefix="sweepcast-scale-") as tmp:
        tmp = Path(tmp)
        warm = tmp / "warm"
        small_survey(warm)  # a few stills, run first: every kernel compiled on every node before the measured run
        _zip(warm)
        # no background warm-up beside the measured job: the warm-up job compiles what the survey needs
        # and no demo rig (its recording job and viewer session would run beside it)
        env = {"SWEEPCAST_DATA_DIR": str(tmp / "data"), "RAY_AUTH_MODE": "disabled", "SWEEPCAST_WARM_KERNELS": "false",
               "SWEEPCAST_DEMO_RIG": "false",
               "SWEEPCAST_MAX_BATCH_BYTES": str(max(2**30, 2 * zip_path.stat().st_size))}
        with ray_cluster(worker_nodes=nodes, cpus_per_node=max(1, cpus // nodes)) as address, \
                serve_app({**env, "SWEEPCAST_RAY_ADDRESS": address}, ready_timeout=300) as app, \
                httpx.Client(base_url=app.base, timeout=60) as client:
            warm_job = _wait(client, _submit(client, warm.with_suffix(".zip")))
            if warm_job["state"] != "succeeded":
                raise RuntimeError(f"the warm-up job failed: {warm_job.get('error')}")
            with NodeSampler(address) as sampler:
                busy0, t0 = machine_busy_seconds(), time.perf_counter()
                job = _wait(client, _submit(client, zip_path, _true_lens(sv) if size in LENS_GIVEN else None))
                wall, busy = time.perf_counter() - t0, machine_busy_seconds() - busy0
            if job["state"] != "succeeded":
                return {**out, "failed": job.get("error")}
            results = tmp / "results"
            results.mkdir()
            for name in ("report.json", "orthophoto.tif", "dsm.tif"):
                (results / name).write_bytes(client.get(f"/v1/jobs/{job['id']}/results/{name}").content)
            sizes = {f["name"]: f["size"] for f in job["result"]["files"]} if job.get("result") else {}
        report = json.loads((results / "report.json").read_text())
        stages = report["stages"]["stages"]
        tasks: dict[str, int] = {}
        for rec in stages.values():
            for node, n in rec.get("tasks_per_node", {}).items():
                tasks[node] = tasks.get(node, 0) + n
        out.update({
            "wall_s": round(wall, 1), "machine_cpu_s": round(busy, 1),
            "peak_rss_mb_per_node": {n[:8]: round(v, 1) for n, v in sampler.peak_mb.items()},
            "cpu_s_per_node": {n[:8]: round(v, 1) for n, v in sampler.cpu_seconds().items()},
            "tasks_per_node": {n[:8]: v for n, v in tasks.items()},
            "stage_seconds": {k: v["seconds"] for k, v in stages.items()},
            "stage_tasks_per_node": {k: {n[:8]: c for n, c in v.get("tasks_per_node", {}).items()}
                                     for k, v in stages.items() if v.get("tasks_per_node")},
            "registered": report["frames"]["registered"], "focal_px": report["intrinsics"]["fx"],
            "submodels": report.get("survey", {}).get("plan", {}).get("submodels"),
            "alignment": report.get("survey", {}).get("alignment"),
            "job_coverage": {k: v for k, v in report["mapping"]["coverage"].items() if k != "note"},
            "gsd_m": report["mapping"]["gsd"], "dense_points": report["dense"]["points"],
            "result_mb": round(sum(sizes.values()) / 2**20, 1),
            "evaluation": evaluate(results, sv),
        })
        _keep_products(size, nodes, results)
    return out


def _true_lens(sv) -> dict[str, Any]:
    """The job parameters that give it the survey's true lens (every still's is the same)."""
    cam = sv.cameras[0]
    return {"fx": float(cam.K[0, 0]), "fy": float(cam.K[1, 1]), "cx": float(cam.K[0, 2]), "cy": float(cam.K[1, 2]),
            "distortion": [float(v) for v in cam.dist]}


def true_focal(size: str) -> float:
    """The focal length (px) of the stills of ``size``."""
    area, size_px = SIZES[size]
    return float(survey_cameras(area, size_px)[0].K[0, 0])


def focal_height_bias(focal_px: float, true_focal_px: float, height_m: float, gsd_m: float) -> float:
    """The DSM's height error (GSD, + above the truth) that a focal length error alone makes on a nadir survey flown
    at ``height_m`` above the ground: the images fix each point's position across the view and its depth only in
    units of the focal length (a longer lens at the same place sees the same images of a farther ground), so the
    ground lies ``height_m * (focal_px / true_focal_px - 1)`` too low."""
    return -height_m * (focal_px / true_focal_px - 1.0) / gsd_m


_KEPT: dict[tuple[str, int], Path] = {}


def _keep_products(size: str, nodes: int, folder: Path) -> None:
    """Keep a run's GeoTIFFs for the comparison of the one-node and two-node runs of one size (this process)."""
    keep = Path(tempfile.mkdtemp(prefix=f"sweepcast-scale-{size}-{nodes}-"))
    for name in ("orthophoto.tif", "dsm.tif"):
        (folder / name).replace(keep / name)
    _KEPT[(size, nodes)] = keep


def products_agreement(a: Path, b: Path) -> dict[str, float] | None:
    """How far two runs' products are apart, run b's resampled (nearest cell) onto run a's grid: the DSMs' median
    absolute difference (in a's GSD) and share within one GSD over the cells both have, the orthophotos' PSNR of one
    against the other where both are coloured; ``same_grid`` whether the grids were identical (two runs of one survey
    agree to the solver's tolerance, not bit for bit, so their grids may differ by a fraction of a cell)."""
    import rasterio

    with rasterio.open(a / "dsm.tif") as sa, rasterio.open(b / "dsm.tif") as sb:
        same = sa.transform == sb.transform and sa.shape == sb.shape
        da = sa.read(1, masked=True)
        db = _on_grid(sb, sa, 1)[0]
        gsd = sa.transform.a
    both = ~np.ma.getmaskarray(da) & np.isfinite(db)
    diff = np.abs(da.data - db)[both] / gsd
    with rasterio.open(a / "orthophoto.tif") as sa, rasterio.open(b / "orthophoto.tif") as sb:
        oa = sa.read()
        ob = _on_grid(sb, sa, sb.count)
    lit = (oa[3] > 0) & np.isfinite(ob[3]) & (ob[3] > 0)
    mse = float(np.mean((oa[:3, lit].astype(np.float64) - ob[:3, lit]) ** 2)) if lit.any() else float("nan")
    return {"same_grid": same, "dsm_median_abs_diff_gsd": float(np.median(diff)) if len(diff) else None,
            "dsm_within_1_gsd": float(np.mean(diff <= 1.0)) if len(diff) else None,
            "orthophoto_psnr_between_db": 10 * math.log10(255**2 / max(mse, 1e-12)) if mse == mse else None}


def _on_grid(src, like, bands: int) -> np.ndarray:
    """``src``'s first ``bands`` bands (an open rasterio dataset) resampled (nearest cell) onto ``like``'s grid:
    (bands, H, W) float32, NaN where src has no data."""
    from rasterio.warp import Resampling, reproject

    out = np.full((bands, *like.shape), np.nan, np.float32)
    for i in range(bands):
        reproject(src.read(i + 1).astype(np.float32), out[i], src_transform=src.transform, src_crs=src.crs,
                  dst_transform=like.transform, dst_crs=like.crs, src_nodata=src.nodata, dst_nodata=np.nan,
                  resampling=Resampling.nearest)
    return out


def bench_scale(sizes: list[str], nodes_list: list[int], cache: Path, previous: dict[str, Any]
                ) -> tuple[dict[str, Any], str]:
    """The runs asked for, merged into the previous results' runs; the section's results and Markdown."""
    cpus = os.cpu_count() or 1
    runs: dict[str, dict[str, Any]] = {k: dict(v) for k, v in previous.get("runs", {}).items()}
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    for size in sizes:
        for nodes in nodes_list:
            print(f"scale: {size} stills on {nodes} node(s)...", flush=True)
            load0 = os.getloadavg()[0]
            try:
                result = run_one(size, nodes, cache, cpus)
            except Exception as exc:  # noqa: BLE001 - one run's failure is a figure, the other runs still count
                result = {"photos": photos_for(*SIZES[size]), "failed": f"{type(exc).__name__}: {exc}"}
            result.update(date=date, load_average_start_end=[round(load0, 2), round(os.getloadavg()[0], 2)],
                          machine_cores=cpus)
            runs.setdefault(size, {})[str(nodes)] = result
            print(json.dumps(result)[:600], flush=True)
        if (size, 1) in _KEPT and (size, 2) in _KEPT:
            runs[size]["agreement_1_vs_2_nodes"] = products_agreement(_KEPT[(size, 1)], _KEPT[(size, 2)])
        for nodes in nodes_list:
            if (size, nodes) in _KEPT:
                shutil.rmtree(_KEPT.pop((size, nodes)), ignore_errors=True)
    out = {"runs": runs, "scaling": _scaling(runs), "sizes": {k: photos_for(*v) for k, v in SIZES.items()}}
    return out, _markdown(out)


def _scaling(runs: dict[str, Any]) -> dict[str, Any]:
    """Per node count: the exponent of wall and CPU in the number of stills from ~110 to ~1,000, and how the peak
    memory per node grew."""
    out = {}
    for nodes in ("1", "2"):
        a, b = runs.get("110", {}).get(nodes), runs.get("1000", {}).get(nodes)
        if not a or not b or "wall_s" not in a or "wall_s" not in b:
            continue
        ratio = math.log(b["photos"] / a["photos"])
        out[nodes] = {"wall_exponent": math.log(b["wall_s"] / a["wall_s"]) / ratio,
                      "cpu_exponent": math.log(b["machine_cpu_s"] / a["machine_cpu_s"]) / ratio,
                      "peak_rss_growth": max(b["peak_rss_mb_per_node"].values()) / max(a["peak_rss_mb_per_node"].values())}
    return out


def _met(ok: bool | None) -> str:
    return "n/a" if ok is None else ("met" if ok else "**not met**")


def _markdown(out: dict[str, Any]) -> str:
    runs = out["runs"]
    order = [s for s in SIZES if s in runs]
    rows, goal_rows = [], []
    for size in order:
        for nodes in ("1", "2"):
            r = runs[size].get(nodes)
            if not r:
                continue
            if "failed" in r:
                rows.append([size, nodes, r["photos"], f"failed: {r['failed'][:80]}"] + [""] * 8)
                continue
            e = r["evaluation"]
            tasks = ", ".join(f"{v}" for v in sorted(r["tasks_per_node"].values(), reverse=True))
            rss = ", ".join(f"{v:.0f}" for v in sorted(r["peak_rss_mb_per_node"].values(), reverse=True))
            stereo = e["orthophoto"].get("psnr_stereo_db")
            rows.append([size, nodes, f"{r['registered']}/{r['photos']}", r["wall_s"], r["machine_cpu_s"], rss, tasks,
                         f"{e['dsm']['coverage']:.4f} / {e['orthophoto']['coverage']:.4f}",
                         f"{e['dsm']['median_abs_gsd']:.2f} / {e['dsm'].get('stereo_median_abs_gsd') or float('nan'):.2f}",
                         f"{e['orthophoto']['psnr_all_db']:.2f} / {stereo or float('nan'):.2f} / "
                         f"{e['orthophoto']['psnr_open_ground_db']:.2f}", f"{r['gsd_m'] * 100:.1f}", r["date"]])
    text = ["### Scale: a survey of any size through the service (issue 57)\n",
            "Synthetic nadir surveys at 60 m (75 % forward, 65 % side overlap, lens k1 -0.05, k2 0.01, EXIF GPS and "
            "focal length only), uploaded as one zip with no parameters to `python -m app serve` on a Ray cluster "
            "started with `ray start` (a head without task CPUs plus 1 or 2 worker nodes sharing this machine's "
            "cores). Wall: upload to the job's end; CPU: the machine's busy CPU seconds meanwhile; memory: each "
            "node's raylet and every process under it (its workers, the job's own on one of them), peak of the "
            "sum. Coverage: the share of the union of every photo's true footprint (its image border through the "
            "lens, on the ground) that the DSM has a height for / the orthophoto a colour for. DSM: median absolute "
            "error in its own cells, in its GSD. PSNR against the scene ray-cast from above on the orthophoto's "
            "cells (open ground: farther than 1 m from any building or tree). Stereo: the cells at least five "
            "photos' true footprints cover, where a depth map can see the ground (a reference and its best four "
            "neighbours); the rest is the survey's rim, whose heights come from sparse points and the fill.\n",
            md_table(["stills", "nodes", "registered", "wall s", "CPU s", "peak RSS per node (MB)",
                      "tasks per node", "coverage DSM / ortho", "DSM median abs, all / stereo (GSD)",
                      "ortho PSNR, all / stereo / open ground (dB)", "GSD (cm)", "measured"], rows)]
    agree = [[s, a.get("dsm_median_abs_diff_gsd"), a.get("dsm_within_1_gsd"), a.get("orthophoto_psnr_between_db")]
             for s in order if (a := runs[s].get("agreement_1_vs_2_nodes"))]
    if agree:
        text += ["\nThe two-node run's products against the one-node run's:\n",
                 md_table(["stills", "DSM median abs diff (GSD)", "DSM within 1 GSD", "orthophoto PSNR between (dB)"],
                          agree)]
    bias = [[size, nodes, f"{r['focal_px']:.1f} ({true:.1f})", f"{(r['focal_px'] / true - 1) * 100:+.2f} %",
             f"{focal_height_bias(r['focal_px'], true, ALTITUDE, r['evaluation']['dsm']['gsd_m']):+.2f}",
             f"{r['evaluation']['dsm']['median_gsd']:+.2f}", f"{r['evaluation']['dsm']['median_abs_gsd']:.2f}"]
            for size in order for nodes in ("1", "2")
            if (r := runs[size].get(nodes)) and "evaluation" in r and (true := true_focal(size))]
    if bias:
        text += [f"\nMost of the DSM's error is a height bias, and the bias follows the focal length's error: at "
                 f"{ALTITUDE:.0f} m a focal length 1 % long puts the ground 0.6 m too low, whatever the tracks (the "
                 "images of a nadir survey tell where a point lies across the view, and its depth only in units of the "
                 "focal length). The EXIF focal length of these stills is 1.1 % long, as a camera's rounded "
                 "FocalLengthIn35mmFilm is; the rows marked +lens give the job the true lens. Heights in the DSM's "
                 "own cells (the orthophoto's cells at 640 x 480; three of them at 12 MP).\n",
                 md_table(["stills", "nodes", "focal length px (true)", "focal error",
                           "height bias it makes (DSM GSD)", "DSM signed median (DSM GSD)", "DSM median abs (DSM GSD)"],
                          bias)]
    for size in order:
        for nodes in ("1", "2"):
            r = runs[size].get(nodes)
            if r and "stage_seconds" in r:
                text.append(f"\n{size} stills, {nodes} node(s), seconds per stage: "
                            + ", ".join(f"{k} {v:.1f}" for k, v in r["stage_seconds"].items()) + ".")
    sc = out["scaling"]
    evaluated = [(s, r) for s in order for r in runs[s].values() if isinstance(r, dict) and "evaluation" in r]
    runs_ok = [r for s, r in evaluated if s not in LENS_GIVEN]
    lens = [(s, r) for s, r in evaluated if s in LENS_GIVEN]
    cov = [min(r["evaluation"]["dsm"]["coverage"], r["evaluation"]["orthophoto"]["coverage"]) for r in runs_ok]
    dsm = [r["evaluation"]["dsm"]["median_abs_gsd"] for r in runs_ok]
    psnr = [r["evaluation"]["orthophoto"]["psnr_all_db"] for r in runs_ok]
    dsm_st = [v for r in runs_ok if (v := r["evaluation"]["dsm"].get("stereo_median_abs_gsd")) is not None]
    psnr_st = [v for r in runs_ok if (v := r["evaluation"]["orthophoto"].get("psnr_stereo_db")) is not None]
    two = [r for s in order if (r := runs[s].get("2")) and "tasks_per_node" in r]
    goal_rows = [
        ["coverage of the true footprints >= 99 % at every size", f"lowest {min(cov):.4f}" if cov else "-",
         _met(min(cov) >= GOALS["coverage"] if cov else None)],
        ["DSM median abs <= 1 GSD at every size", f"highest {max(dsm):.2f}" if dsm else "-",
         _met(max(dsm) <= GOALS["dsm_gsd"] if dsm else None)],
        ["... where five photos or more saw the ground", f"highest {max(dsm_st):.2f}" if dsm_st else "-",
         _met(max(dsm_st) <= GOALS["dsm_gsd"] if dsm_st else None)],
        ["orthophoto >= 30 dB at every size", f"lowest {min(psnr):.2f}" if psnr else "-",
         _met(min(psnr) >= GOALS["ortho_db"] if psnr else None)],
        ["... where five photos or more saw the ground", f"lowest {min(psnr_st):.2f}" if psnr_st else "-",
         _met(min(psnr_st) >= GOALS["ortho_db"] if psnr_st else None)],
        *[[f"with the true lens given ({s}, {r['nodes']} node(s)): DSM <= 1 GSD, orthophoto >= 30 dB",
           f"{r['evaluation']['dsm']['median_abs_gsd']:.2f} GSD, {r['evaluation']['orthophoto']['psnr_all_db']:.2f} dB",
           _met(r["evaluation"]["dsm"]["median_abs_gsd"] <= GOALS["dsm_gsd"]
                and r["evaluation"]["orthophoto"]["psnr_all_db"] >= GOALS["ortho_db"])] for s, r in lens],
        *[[f"cost exponent in stills, 110 -> 1,000, {n} node(s) (<= 1.1)",
           f"wall {v['wall_exponent']:.2f}, CPU {v['cpu_exponent']:.2f}",
           _met(max(v["wall_exponent"], v["cpu_exponent"]) <= GOALS["exponent"])] for n, v in sc.items()],
        *[[f"peak RSS per node, 1,000 / 110 stills, {n} node(s) (<= 1.5x)", f"{v['peak_rss_growth']:.2f}x",
           _met(v["peak_rss_growth"] <= GOALS["rss_growth"])] for n, v in sc.items()],
        ["both nodes busy on the cluster runs", "; ".join(
            f"{len(r['tasks_per_node'])} nodes ran tasks ({r['photos']} stills)" for r in two) or "-",
         _met(all(len(r["tasks_per_node"]) >= 2 for r in two) if two else None)],
    ]
    text += ["\n" + md_table(["goal", "measured", ""], goal_rows)]
    return "\n".join(text) + "\n"


def parse_sizes(text: str) -> list[str]:
    sizes = [s.strip() for s in text.split(",") if s.strip()]
    unknown = [s for s in sizes if s not in SIZES]
    if unknown:
        raise SystemExit(f"unknown scale size(s) {', '.join(unknown)}; the sizes: {', '.join(SIZES)}")
    return sizes


def parse_nodes(text: str) -> list[int]:
    nodes = [int(v) for v in re.split(r"[, ]+", text.strip()) if v]
    if not nodes or any(n not in (1, 2) for n in nodes):
        raise SystemExit("--scale-nodes takes 1, 2 or 1,2")
    return nodes
