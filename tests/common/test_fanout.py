"""A job that fans out on Ray: its tasks run at once on the cluster's CPUs, a lost one runs again, an input error
fails the job at once, and the files its tasks write are published with its results."""
from __future__ import annotations

import importlib
import os
import sys
import time
import uuid
from dataclasses import asdict
from pathlib import Path
from typing import Any, Callable

import pytest
import ray
from pydantic import BaseModel

from harness.servers import alive
from workers import fanout
from workers.common.jobctx import JobInputError
from workers.fanout import OnRay
from workers.registry import JobKind
from workers.runtime import JobSpec
from workers.storage import DirectoryBlobStore


class _NoParams(BaseModel):
    pass


@ray.remote(num_cpus=1, max_retries=0)
def _attempt(spec: dict[str, Any], entry: Callable[[Any], dict]) -> Any:
    """One attempt of a job whose entry is ``entry``, run as the dispatcher runs one (``run_job_task``)."""
    from workers import runtime

    real = runtime.get_kind
    runtime.get_kind = lambda name: JobKind(name, entry, _NoParams)
    try:
        yield from runtime.execute_job(JobSpec(**spec), on_ray=True)
    finally:  # this worker process runs other tests' tasks next
        runtime.get_kind = real


def run_attempt(store: DirectoryBlobStore, entry: Callable[[Any], dict], job_id: str = "j1") -> list[dict]:
    spec = JobSpec(job_id, "test.fanout", {}, {}, store_url=store.url)
    return [ray.get(ref) for ref in _attempt.remote(asdict(spec), entry)]


def _sleep_and_tell(seconds: float) -> dict[str, float]:
    start = time.time()
    time.sleep(seconds)
    return {"pid": os.getpid(), "start": start, "end": time.time()}


def _four_sleepers(ctx) -> dict:
    fan = ctx.fanout()
    assert fan.parallelism == 2  # the test cluster's CPUs
    runs = dict(fan.run(_sleep_and_tell, [1.0] * 4))
    return {"runs": [runs[i] for i in range(4)]}


def test_a_job_runs_its_tasks_on_every_cpu_at_once(ray_local, tmp_path):
    """The job's own task waits for its tasks without holding its CPU: on 2 CPUs two tasks run side by side (a wait
    in the job's thread kept the CPU, and they ran one at a time)."""
    events = run_attempt(DirectoryBlobStore(tmp_path / "store"), _four_sleepers)
    assert events[-1]["type"] == "succeeded", events[-1]
    runs = events[-1]["manifest"]["summary"]["runs"]
    overlapping = [(a, b) for i, a in enumerate(runs) for b in runs[i + 1:]
                   if a["start"] < b["end"] and b["start"] < a["end"]]
    assert overlapping and all(a["pid"] != b["pid"] for a, b in overlapping)


def _crash_once(marker: str) -> str:
    path = Path(marker)
    if not path.exists():
        path.write_text("crashed here once")
        os._exit(1)  # the worker process dies, as one killed or out of memory does
    return path.name


def _crashing_tasks(ctx) -> dict:
    folder = Path(ctx.input_meta["folder"]["path"])  # the test's folder, for the tasks' marks
    markers = [str(folder / f"task-{i}") for i in range(3)]
    return {"results": [value for _, value in sorted(ctx.fanout().run(_crash_once, markers))]}


def test_a_task_whose_worker_dies_is_run_again(ray_local, tmp_path):
    store = DirectoryBlobStore(tmp_path / "store")
    spec = JobSpec("j2", "test.fanout", {}, {}, {"folder": {"path": str(tmp_path)}}, store_url=store.url)
    events = [ray.get(ref) for ref in _attempt.remote(asdict(spec), _crashing_tasks)]
    assert events[-1]["type"] == "succeeded", events[-1]
    assert events[-1]["manifest"]["summary"]["results"] == ["task-0", "task-1", "task-2"]
    assert sorted(p.name for p in tmp_path.glob("task-*")) == ["task-0", "task-1", "task-2"]  # each crashed once


def _refuse(task: int) -> int:
    if task == 1:
        raise JobInputError(f"task {task} cannot be done with this input")
    return task


def _one_refusing_task(ctx) -> dict:
    return {"done": [value for _, value in ctx.fanout().run(_refuse, [0, 1, 2])]}


def test_an_input_error_of_a_task_fails_the_job_with_its_message(ray_local, tmp_path):
    events = run_attempt(DirectoryBlobStore(tmp_path / "store"), _one_refusing_task)
    assert events[-1] == {**events[-1], "type": "failed", "user_error": True,
                          "error": "task 1 cannot be done with this input"}


def _refuse_or_import(task: tuple[int, str, str]) -> int:
    """Task 0 refuses its input once task 1 is half-way through importing ``package`` (its ``__init__`` sleeps)."""
    index, folder, package = task
    started = Path(folder) / "started"
    if index == 0:
        deadline = time.monotonic() + 60
        while not started.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)
        raise JobInputError("refused while the other task imports")
    sys.path.insert(0, folder)
    started.write_text(str(os.getpid()))
    importlib.import_module(package)
    return os.getpid()


def _read_part(task: tuple[str, str]) -> int:
    folder, package = task
    sys.path.insert(0, folder)
    return importlib.import_module(package).part.VALUE


def test_a_task_cut_short_by_the_job_leaves_no_worker_with_a_half_imported_module(ray_local, tmp_path):
    """The job stops at one task's input error while another task imports a package: Ray's plain cancel raised
    KeyboardInterrupt inside that import and kept the worker, which ran later tasks with the package half-imported
    (two CI runs: ``module 'numba' has no attribute 'core'`` in the next render job). The worker is ended instead,
    and later tasks import the package whole."""
    package = f"slowpkg_{uuid.uuid4().hex[:8]}"
    (tmp_path / package).mkdir()
    (tmp_path / package / "part.py").write_text("VALUE = 7\n")
    (tmp_path / package / "__init__.py").write_text("from . import part\nimport time\ntime.sleep(5)\n")
    tasks = [(0, str(tmp_path), package), (1, str(tmp_path), package)]
    with pytest.raises(JobInputError, match="refused while the other task imports"):
        list(OnRay().run(_refuse_or_import, tasks))
    importer = int((tmp_path / "started").read_text())
    deadline = time.monotonic() + 30
    while alive(importer) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not alive(importer), "the worker whose import was cut short still runs tasks"
    assert [value for _, value in OnRay().run(_read_part, [(str(tmp_path), package)] * 4)] == [7] * 4


def test_a_task_whose_numba_import_fails_says_so_instead_of_running(monkeypatch):
    """The task's error names the import; passed over, the task ran on and failed at its first kernel instead."""
    monkeypatch.setitem(sys.modules, "numba", None)  # what importing it then raises: ImportError
    ran = []
    with pytest.raises(ImportError, match="numba"):
        fanout.run_task(ran.append, 1)
    assert ran == []


def _write_a_file(work) -> int:
    return work.put("files/out/a.txt", b"made by a task")


def _publishing_entry(ctx) -> dict:
    [(_, size)] = list(ctx.fanout().run(_write_a_file, [ctx.work_area()]))
    ctx.adopt_result("out/a.txt", "files/out/a.txt", size)
    ctx.write_result("summary.txt", b"made by the job")
    return {}


def test_the_files_a_task_wrote_are_published_and_its_work_area_goes(ray_local, tmp_path):
    store = DirectoryBlobStore(tmp_path / "store")
    events = run_attempt(store, _publishing_entry, "j4")
    assert events[-1]["type"] == "succeeded", events[-1]
    assert {f["name"]: f["size"] for f in events[-1]["manifest"]["files"]} == {"out/a.txt": 14, "summary.txt": 15}
    assert store.read("jobs/j4/results/out/a.txt") == b"made by a task"
    assert store.list("jobs/j4") == ["jobs/j4/results/out/a.txt", "jobs/j4/results/summary.txt"]


@pytest.mark.parametrize("nodes,expected", [
    ([("a", 3), ("b", 1)], ["a", "b", "a", "a", "a", "b"]),
    ([("a", 2)], ["a", "a", "a"]),
])
def test_tasks_routed_to_nodes_are_spread_by_their_cpus(nodes, expected):
    from itertools import islice

    from workers.fanout import _spread

    assert list(islice(_spread(nodes), len(expected))) == expected
    assert _spread([]) is None


def test_tasks_of_a_routed_job_go_to_the_nodes_that_offer_its_resources():
    from types import SimpleNamespace

    from workers.fanout import _routed_nodes

    def fake_ray(given: dict[str, float]) -> SimpleNamespace:
        nodes = [{"NodeID": "api", "Alive": True, "Resources": {"CPU": 0.0, "sweepcast_worker": 1.0}},
                 {"NodeID": "gpu", "Alive": True, "Resources": {"CPU": 8.0, "GPU": 1.0}},
                 {"NodeID": "w1", "Alive": True, "Resources": {"CPU": 4.0, "sweepcast_worker": 1.0}},
                 {"NodeID": "w2", "Alive": False, "Resources": {"CPU": 4.0, "sweepcast_worker": 1.0}},
                 {"NodeID": "w3", "Alive": True, "Resources": {"CPU": 2.0, "sweepcast_worker": 1.0}}]
        context = SimpleNamespace(get_assigned_resources=lambda: given)
        return SimpleNamespace(get_runtime_context=lambda: context, nodes=lambda: nodes)

    # live, with CPUs, offering the job's own custom resource
    assert _routed_nodes(fake_ray({"CPU": 1.0, "sweepcast_worker": 1.0})) == [("w1", 4), ("w3", 2)]
    assert _routed_nodes(fake_ray({"CPU": 1.0})) == []  # not routed: wherever Ray places them
