"""The kernel cache the service owns: where it is, the warm-up that fills it, and what readiness says."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.kernelcache import KernelWarmup
from app.main import create_app
from app.raycluster import worker_env
from app.settings import Settings

ROOT = Path(__file__).resolve().parents[2]


def _index_files(cache: Path, module: str) -> list[Path]:
    return [p for p in cache.rglob("*.nbi") if p.name.startswith(module)]


def test_the_cache_is_the_setting_else_numba_cache_dir_else_the_users_for_every_data_folder(tmp_path, monkeypatch):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    for data in ("a", "b"):  # kernels and the demo recording depend on the code, not on the data folder
        settings = Settings(data_dir=tmp_path / data)
        assert settings.resolved_numba_cache_dir == (tmp_path / "xdg" / "sweepcast" / "kernels").resolve()
        assert settings.resolved_demo_cache_dir == (tmp_path / "xdg" / "sweepcast" / "demo").resolve()
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba-env"))
    assert Settings(data_dir=tmp_path).resolved_numba_cache_dir == (tmp_path / "numba-env").resolve()
    chosen = Settings(data_dir=tmp_path, numba_cache_dir=tmp_path / "chosen")
    assert chosen.resolved_numba_cache_dir == (tmp_path / "chosen").resolve()
    assert worker_env(chosen)["NUMBA_CACHE_DIR"] == str((tmp_path / "chosen").resolve())  # its Ray workers too
    assert worker_env(chosen)["SWEEPCAST_DEMO_CACHE_DIR"] == str((tmp_path / "xdg" / "sweepcast" / "demo").resolve())


def test_sweepcast_warmup_compiles_into_the_users_cache(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["XDG_CACHE_HOME"] = str(tmp_path / "xdg")
    done = subprocess.run([sys.executable, "-m", "app", "warmup", "faces", "--data-dir", str(tmp_path / "data")],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert '"faces"' in done.stdout.splitlines()[-1]
    user = tmp_path / "xdg" / "sweepcast"
    assert _index_files(user / "kernels", "preview._rasterise")  # the face preview's kernel
    assert not (user / "demo").exists()  # the demo's recording only with the demo's kernels


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
        deadline = time.monotonic() + 30
        while Path(os.readlink(f"/proc/{warm.proc.pid}/exe")).name == "nice":  # `nice` sets it, then execs Python
            assert time.monotonic() < deadline
            time.sleep(0.01)
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
    os.utime(source, ns=(source.stat().st_atime_ns, source.stat().st_mtime_ns + 1_000_000))  # touched: same code
    assert warmup.is_current(cache)
    source.write_text("x = 2\n")  # an edited source
    assert not warmup.is_current(cache)
    warm = KernelWarmup.start(cache, engines=("faces",))  # a warm-up of some engines always runs
    warm.stop()
    assert warm.proc is not None


_FACES_IN_A_COPY = """
import json, sys
from workers import warmup
from workers.faces.preview import _rasterise
warmup.warm(["faces"])
print(json.dumps({"file": _rasterise.py_func.__code__.co_filename, "hits": sum(_rasterise.stats.cache_hits.values()),
                  "misses": sum(_rasterise.stats.cache_misses.values())}))
"""


def test_kernels_compiled_in_one_install_load_in_another_at_another_path(tmp_path):
    """numba files kernels by a hash of the source's absolute folder; ours go by their path in the project, so a
    cache compiled ahead (an image build, another checkout) serves any install of the same sources."""
    import shutil

    cache = tmp_path / "cache"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    subprocess.run([sys.executable, "-m", "workers.warmup", "--jobs", "1", "faces"], cwd=ROOT, env=env, check=True,
                   capture_output=True)
    assert [p.name for p in cache.iterdir()] == ["workers_faces"]
    other = tmp_path / "elsewhere"
    shutil.copytree(ROOT / "workers", other / "workers", ignore=shutil.ignore_patterns("__pycache__"))
    done = subprocess.run([sys.executable, "-c", _FACES_IN_A_COPY], cwd=other, env={**env, "PYTHONPATH": str(other)},
                          check=True, capture_output=True, text=True)
    loaded = json.loads(done.stdout.strip().splitlines()[-1])
    assert loaded["file"].startswith(str(other)) and loaded["hits"] >= 1 and loaded["misses"] == 0


def test_the_kernels_a_wheel_carries_are_the_default_ones_compiled_ahead(tmp_path, monkeypatch):
    from app import settings as settings_module

    monkeypatch.delenv("SWEEPCAST_PREBUILT_KERNELS", raising=False)
    shipped = tmp_path / "_prebuilt"
    monkeypatch.setattr(settings_module, "SHIPPED_KERNELS", shipped / "kernels")
    assert Settings(data_dir=tmp_path).resolved_prebuilt_kernels is None  # a checkout carries none
    (shipped / "kernels").mkdir(parents=True)
    assert Settings(data_dir=tmp_path).resolved_prebuilt_kernels is None  # nor does a build that stamped nothing
    (shipped / "kernels" / "warmed.json").write_text("{}")
    assert Settings(data_dir=tmp_path).resolved_prebuilt_kernels == shipped / "kernels"
    mine = Settings(data_dir=tmp_path, prebuilt_kernels=tmp_path / "mine")
    assert mine.resolved_prebuilt_kernels == tmp_path / "mine"  # the setting wins


def test_a_wheel_carries_the_kernels_and_demo_recording_its_build_puts_in_the_sources(tmp_path):
    """pyproject's package data takes what packaging/build-wheel.sh compiles into the copy it builds the wheel
    from (``workers/_prebuilt``: the stamp, one folder of kernels per package, the demo recording)."""
    import zipfile

    listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard", "--",
                             "pyproject.toml", "README.md", "app", "workers"], cwd=ROOT, check=True,
                            capture_output=True).stdout.decode().split("\0")
    src = tmp_path / "src"
    for name in filter(None, listed):
        if (ROOT / name).is_file():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            (src / name).write_bytes((ROOT / name).read_bytes())
    shipped = ["workers/_prebuilt/kernels/warmed.json", "workers/_prebuilt/kernels/workers_sweep/kernels.f-12.py311.nbi",
               "workers/_prebuilt/kernels/workers_sweep/kernels.f-12.py311.1.nbc", "workers/_prebuilt/demo/0123abcd.zip"]
    for name in shipped:
        (src / name).parent.mkdir(parents=True, exist_ok=True)
        (src / name).write_bytes(name.encode())
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--wheel-dir", str(tmp_path / "out"),
                    str(src)], check=True, capture_output=True)
    (wheel,) = (tmp_path / "out").glob("sweepcast-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert set(shipped) <= names and "workers/streaming/demo.py" in names
    static = {name for name in listed if name.startswith("app/static/")}
    assert "app/static/render/shaders/fill.frag" in static and static <= names  # the pages and the browser renderer


def _prebuilt(tmp_path: Path, fingerprint: str | None = None) -> Path:
    """A read-only kernel cache stamped as ``sweepcast warmup --target x86-64-v3`` stamps it (one kernel file)."""
    from workers.portable_cache import target_features
    from workers.warmup import STAMP_NAME, fingerprint as code_fingerprint

    features = target_features("x86-64-v3")
    prebuilt = tmp_path / "prebuilt"
    (prebuilt / "workers_faces").mkdir(parents=True)
    (prebuilt / "workers_faces" / "preview._rasterise-20.py311.nbi").write_bytes(b"index")
    (prebuilt / STAMP_NAME).write_text(json.dumps({"fingerprint": fingerprint or code_fingerprint(("x86-64-v3", features)),
                                                   "cpu_name": "x86-64-v3", "cpu_features": features}))
    for path in (prebuilt / "workers_faces" / "preview._rasterise-20.py311.nbi", prebuilt / STAMP_NAME,
                 prebuilt / "workers_faces", prebuilt):
        path.chmod(0o555 if path.is_dir() else 0o444)
    return prebuilt


_USE_PREBUILT = """
import json, os, sys
from pathlib import Path
from app.kernelcache import use_prebuilt
state = use_prebuilt(Path(sys.argv[1]), Path(sys.argv[2]))
print(json.dumps({**state, "cpu": os.environ.get("NUMBA_CPU_NAME"), "numba": "numba" in sys.modules}))
"""


def test_kernels_compiled_ahead_for_a_baseline_this_cpu_runs_are_copied_and_their_target_set(tmp_path):
    from workers.portable_cache import host_supports
    from workers.warmup import is_current

    if host_supports("x86-64-v3"):
        pytest.skip("this CPU does not run x86-64-v3 code")
    prebuilt, cache = _prebuilt(tmp_path), tmp_path / "cache"
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CPU_")}
    done = subprocess.run([sys.executable, "-c", _USE_PREBUILT, str(prebuilt), str(cache)], cwd=ROOT, env=env,
                          check=True, capture_output=True, text=True)
    state = json.loads(done.stdout.strip().splitlines()[-1])
    assert state["state"] == "used" and state["cpu"] == "x86-64-v3" and not state["numba"], state
    assert (cache / "workers_faces" / "preview._rasterise-20.py311.nbi").read_bytes() == b"index"
    assert is_current(cache, ("x86-64-v3", json.loads((cache / "warmed.json").read_text())["cpu_features"]))
    assert "(2 files copied into" in state["detail"]


def test_kernels_compiled_ahead_are_not_used_for_other_code_or_on_a_cpu_without_the_baseline(tmp_path, monkeypatch):
    from app import kernelcache
    from workers import portable_cache

    cache = tmp_path / "cache"
    stale = _prebuilt(tmp_path / "a", fingerprint="0" * 64)
    monkeypatch.delenv("NUMBA_CPU_NAME", raising=False)
    state = kernelcache.use_prebuilt(stale, cache)
    assert state["state"] == "not used" and "other sources" in state["detail"] and "NUMBA_CPU_NAME" not in os.environ
    monkeypatch.setattr(portable_cache, "host_supports", lambda name: ["avx2", "fma"])
    state = kernelcache.use_prebuilt(_prebuilt(tmp_path / "b"), cache)
    assert state["state"] == "not used" and "lacks avx2, fma of the x86-64-v3 target" in state["detail"]
    assert "NUMBA_CPU_NAME" not in os.environ and not (cache / "workers_faces").exists()
    assert KernelWarmup(current=True).status()["prebuilt"] == state  # /readyz says so
    assert kernelcache.use_prebuilt(None, cache) == {} and "prebuilt" not in KernelWarmup(current=True).status()


def test_kernel_env_exports_the_cache_and_the_prebuilt_target_for_a_containers_processes(tmp_path):
    from workers.portable_cache import host_supports

    if host_supports("x86-64-v3"):
        pytest.skip("this CPU does not run x86-64-v3 code")
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CPU_") and k != "NUMBA_CACHE_DIR"}
    env.update(XDG_CACHE_HOME=str(tmp_path / "xdg"), SWEEPCAST_PREBUILT_KERNELS=str(_prebuilt(tmp_path)))
    done = subprocess.run([sys.executable, "-m", "app", "kernel-env", "--data-dir", str(tmp_path / "data")], cwd=ROOT,
                          env=env, check=True, capture_output=True, text=True)
    exports = dict(line.removeprefix("export ").split("=", 1) for line in done.stdout.splitlines())
    assert exports["NUMBA_CACHE_DIR"] == str((tmp_path / "xdg" / "sweepcast" / "kernels").resolve())
    assert exports["NUMBA_CPU_NAME"] == "x86-64-v3" and "+avx2" in exports["NUMBA_CPU_FEATURES"]
    assert "using the kernels compiled ahead for x86-64-v3" in done.stderr  # the container's log says so
