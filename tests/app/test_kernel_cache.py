"""The kernel cache the service owns: where it is, the warm-up that fills it, and what readiness says."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

from fastapi.testclient import TestClient

from app.kernelcache import KernelWarmup
from app.main import create_app
from app.raycluster import worker_env
from app.settings import Settings

ROOT = Path(__file__).resolve().parents[2]


def _index_files(cache: Path, module: str) -> list[Path]:
    return [p for p in cache.rglob("*.nbi") if p.name.startswith(module)]


def test_the_cache_is_the_setting_else_numba_cache_dir_else_inside_the_data_folder(tmp_path, monkeypatch):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    assert Settings(data_dir=tmp_path).resolved_numba_cache_dir == (tmp_path / "cache" / "numba").resolve()
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba-env"))
    assert Settings(data_dir=tmp_path).resolved_numba_cache_dir == (tmp_path / "numba-env").resolve()
    chosen = Settings(data_dir=tmp_path, numba_cache_dir=tmp_path / "chosen")
    assert chosen.resolved_numba_cache_dir == (tmp_path / "chosen").resolve()
    assert worker_env(chosen)["NUMBA_CACHE_DIR"] == str((tmp_path / "chosen").resolve())  # its Ray workers too
    assert worker_env(chosen)["SWEEPCAST_DEMO_CACHE_DIR"] == str((tmp_path / "cache" / "demo").resolve())


def test_sweepcast_warmup_compiles_into_the_data_folders_cache(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    done = subprocess.run([sys.executable, "-m", "app", "warmup", "faces", "--data-dir", str(tmp_path)], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert '"faces"' in done.stdout.splitlines()[-1]
    assert _index_files(tmp_path / "cache" / "numba", "preview._rasterise")  # the face preview's kernel
    assert not (tmp_path / "cache" / "demo").exists()  # the demo's recording only with the demo's kernels


def test_an_unknown_engine_is_refused():
    done = subprocess.run([sys.executable, "-m", "workers.warmup", "teleport"], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 2 and "unknown engine(s) teleport" in done.stderr


def test_the_background_warmup_reports_warming_then_its_seconds(tmp_path):
    warm = KernelWarmup.start(tmp_path, engines=("faces",))
    assert warm.status()["state"] == "warming"
    deadline = time.monotonic() + 300
    while warm.state == "warming" and time.monotonic() < deadline:
        time.sleep(0.2)
    status = warm.status()
    assert status["ok"] and status["state"] == "done" and set(status["seconds"]) == {"faces"}
    assert _index_files(tmp_path, "preview._rasterise")


def test_readiness_reports_the_kernels_and_never_waits_for_them(settings_factory, ray_local):
    with TestClient(create_app(settings_factory(warm_kernels=False))) as client:
        kernels = client.get("/readyz").json()["checks"]["kernels"]
    assert kernels == {"ok": True, "state": "off"}


def test_engines_are_shared_out_by_compile_time_and_keep_their_order():
    from workers.warmup import ENGINES, shares

    assert shares(list(ENGINES), 1) == [list(ENGINES)]
    two = shares(list(ENGINES), 2)
    assert sorted(sum(two, [])) == sorted(ENGINES) and len(two) == 2
    assert ["sweep", "demo", "faces"] in two and ["drone", "dense", "depth"] in two  # ~82 s each on 2 cores
    assert shares(["faces"], 4) == [["faces"]]  # never an idle process


def test_warming_in_two_processes_reports_every_engine(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    done = subprocess.run([sys.executable, "-m", "workers.warmup", "--jobs", "2", "faces", "depth"], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert set(json.loads(done.stdout.splitlines()[-1])) == {"faces", "depth"}
    assert _index_files(tmp_path, "preview._rasterise")


def test_stopping_the_warmup_ends_its_compiling_processes(tmp_path):
    warm = KernelWarmup.start(tmp_path, engines=("sweep", "drone"))
    deadline = time.monotonic() + 60
    children: list[int] = []
    while not children and time.monotonic() < deadline:  # its two compiling processes
        children = [int(p) for p in subprocess.run(["pgrep", "-P", str(warm.proc.pid)], capture_output=True,
                                                    text=True).stdout.split()]
        time.sleep(0.1)
    assert children
    warm.stop()
    time.sleep(0.5)
    assert all(not Path(f"/proc/{pid}").exists() or "zombie" in Path(f"/proc/{pid}/status").read_text()
               for pid in children)


def test_the_warmup_yields_the_cpu_to_rays_workers(tmp_path):
    warm = KernelWarmup.start(tmp_path, engines=("faces",))
    try:
        nice = int(Path(f"/proc/{warm.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()[16])
    finally:
        warm.stop()
    assert nice > 15  # Ray's worker processes run at nice 15


def _fake_engines(monkeypatch, tmp_path):
    from workers import warmup

    monkeypatch.setattr(warmup, "ENGINES", {name: (lambda: None) for name in warmup.ENGINES})
    sources = tmp_path / "sources"
    sources.mkdir()
    (sources / "kernels.py").write_text("x = 1\n")
    monkeypatch.setattr(warmup, "_WORKERS", sources)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    (tmp_path / "cache").mkdir()
    return warmup, sources / "kernels.py"


def test_a_full_warmup_stamps_the_cache_and_the_next_start_only_checks_it(tmp_path, monkeypatch, capsys):
    warmup, source = _fake_engines(monkeypatch, tmp_path)
    cache = tmp_path / "cache"
    assert warmup.main(["--jobs", "1", "faces", "depth"]) == 0 and not warmup.is_current(cache)  # not every engine
    assert warmup.main(["--jobs", "1"]) == 0 and warmup.is_current(cache)
    started = KernelWarmup.start(cache)
    assert started.proc is None and started.state == "done" and "current" in started.status()["detail"]
    os.utime(source, ns=(source.stat().st_atime_ns, source.stat().st_mtime_ns + 1_000_000))  # an edited source
    assert not warmup.is_current(cache)
    warm = KernelWarmup.start(cache, engines=("faces",))  # a warm-up of some engines always runs
    warm.stop()
    assert warm.proc is not None
