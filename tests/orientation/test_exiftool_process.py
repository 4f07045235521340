"""The kept-open exiftool process never outlives its user (exiftool -stay_open ignores the end of its input)."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from workers.orientation import exiftool

pytestmark = pytest.mark.skipif(shutil.which("exiftool") is None, reason="exiftool is not installed")
ROOT = Path(__file__).resolve().parents[2]


def _gone(pid: int, timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        try:  # a zombie of ours counts as gone
            if Path(f"/proc/{pid}/stat").read_text().split()[2] == "Z":
                return True
        except OSError:
            return True
        time.sleep(0.05)
    return False


def test_the_process_of_a_finished_thread_is_stopped():
    pids = []

    def work() -> None:
        exiftool.run(["-ver"])
        pids.append(exiftool._local.proc._proc.pid)

    thread = threading.Thread(target=work)
    thread.start()
    thread.join()
    assert pids and _gone(pids[0])


def test_the_process_of_a_killed_user_is_stopped():
    user = subprocess.Popen([sys.executable, "-c", "from workers.orientation import exiftool; exiftool.run(['-ver']); "
                             "print(exiftool._local.proc._proc.pid, flush=True); import time; time.sleep(60)"],
                            cwd=ROOT, stdout=subprocess.PIPE, text=True)
    pid = int(user.stdout.readline())
    user.kill()
    user.wait()
    assert _gone(pid)
