"""The harness's readers of /proc (benchmarks and tests): memory, CPU time and the process tree, with NaN for a process
that is gone."""
from __future__ import annotations

import math
import os
import subprocess
import sys
import time

import pytest

from harness.proc import cpu_seconds, descendants, status, status_mb, tree_cpu_seconds

pytestmark = pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="needs Linux's /proc")
GONE = 2**22 + 1  # above the kernel's largest pid


def test_memory_fields_in_megabytes_and_nan_when_gone():
    fields = status(os.getpid())
    assert status_mb(os.getpid(), "VmRSS", fields) == int(fields["VmRSS"].split()[0]) / 1024 > 10
    assert status_mb(os.getpid(), "VmHWM") >= status_mb(os.getpid(), "VmRSS") - 1
    assert math.isnan(status_mb(os.getpid(), "NoSuchField"))
    assert status(GONE) == {} and math.isnan(status_mb(GONE, "VmRSS")) and math.isnan(cpu_seconds(GONE))


def test_cpu_seconds_count_the_work_done():
    before, t = cpu_seconds(os.getpid()), time.process_time()
    while time.process_time() - t < 0.5:
        sum(range(10_000))
    assert 0.3 < cpu_seconds(os.getpid()) - before < 1.5


def test_the_tree_holds_grandchildren_and_their_cpu():
    busy = "import time\nt = time.process_time()\nwhile time.process_time() - t < 0.4: pass\ntime.sleep(30)"
    parent = subprocess.Popen([sys.executable, "-c", f"import subprocess, sys, time\n"
                               f"subprocess.Popen([sys.executable, '-c', {busy!r}])\ntime.sleep(30)"])
    try:
        deadline = time.monotonic() + 20
        while len(tree := descendants(parent.pid)) < 2 or tree_cpu_seconds(parent.pid) - cpu_seconds(parent.pid) < 0.3:
            assert time.monotonic() < deadline, tree
            time.sleep(0.1)
        assert tree[0] == parent.pid and len(tree) == 2
        assert descendants(GONE) == [GONE] and tree_cpu_seconds(GONE) == 0
    finally:
        for pid in reversed(descendants(parent.pid)):
            os.kill(pid, 9)
        parent.wait()


def test_reaped_children_count_only_when_asked():
    busy = "import time\nt = time.process_time()\nwhile time.process_time() - t < 0.4: pass"
    parent = subprocess.Popen([sys.executable, "-c", f"import subprocess, sys, time\n"
                               f"subprocess.run([sys.executable, '-c', {busy!r}])\ntime.sleep(30)"])
    try:
        deadline = time.monotonic() + 20
        while cpu_seconds(parent.pid, reaped=True) - cpu_seconds(parent.pid) < 0.3:  # the child ran, was waited for
            assert time.monotonic() < deadline
            time.sleep(0.1)
        assert descendants(parent.pid) == [parent.pid]  # it is gone: only the reaped count still has its CPU
        assert tree_cpu_seconds(parent.pid, reaped=True) - tree_cpu_seconds(parent.pid) >= 0.3
    finally:
        parent.kill()
        parent.wait()
