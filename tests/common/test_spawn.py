"""Children set up without Python between fork and exec (workers/common/spawn.py): the parent-death signal and the
niceness still take effect, and no code of ours passes ``preexec_fn`` (a deadlock in a threaded process: CI stop 71)."""
from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from workers.common.spawn import dying_with_parent, niced

ROOT = Path(__file__).resolve().parents[2]
ON_LINUX_WITH_SETPRIV = sys.platform.startswith("linux") and shutil.which("setpriv") is not None


def _ended(proc: subprocess.Popen, timeout: float = 10.0) -> bool:
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        return False
    return True


def _running(proc: subprocess.Popen, program: str, timeout: float = 10.0) -> bool:
    """Whether the child has exec'd ``program`` (so setpriv, before it, has set its parent-death signal)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            if Path(os.readlink(f"/proc/{proc.pid}/exe")).name == program:
                return True
        except OSError:
            pass
        time.sleep(0.01)
    return False


@pytest.mark.skipif(not ON_LINUX_WITH_SETPRIV, reason="needs Linux and util-linux's setpriv")
def test_a_child_ends_with_the_thread_that_started_it():
    started: list[subprocess.Popen] = []
    ran: list[bool] = []

    def work() -> None:
        started.append(subprocess.Popen(dying_with_parent(["sleep", "60"])))
        ran.append(_running(started[0], "sleep"))

    thread = threading.Thread(target=work)
    thread.start()
    thread.join()
    assert ran == [True]
    assert _ended(started[0])
    assert started[0].returncode == -15  # SIGTERM, from the kernel


@pytest.mark.skipif(not ON_LINUX_WITH_SETPRIV, reason="needs Linux and util-linux's setpriv")
def test_a_child_of_a_living_thread_runs_on():
    proc = subprocess.Popen(dying_with_parent(["sleep", "60"]))
    try:
        time.sleep(0.5)
        assert proc.poll() is None
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.skipif(shutil.which("nice") is None, reason="needs coreutils' nice")
def test_a_niced_child_runs_that_many_steps_below_its_parent():
    proc = subprocess.Popen(niced([sys.executable, "-c", "import os; print(os.nice(0))"], 5), stdout=subprocess.PIPE,
                            text=True)
    out, _ = proc.communicate(timeout=30)
    assert int(out) == min(os.nice(0) + 5, 19)


def test_no_code_of_ours_runs_python_in_a_forked_child():
    offenders = []
    for folder in ("app", "workers", "harness", "benchmarks", "tests"):
        for path in (ROOT / folder).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.keyword) and node.arg == "preexec_fn":
                    offenders.append(f"{path.relative_to(ROOT)}:{node.value.lineno}")
    assert not offenders, f"preexec_fn can deadlock a threaded process's child (use workers.common.spawn): {offenders}"
