"""The throw-away servers of harness/servers.py never outlive their starter, whether it gets SIGTERM
(the benchmarks' exit_on_sigterm) or SIGKILL (the watchdog, and the kernel's parent-death signal)."""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from harness.servers import ROOT, postgres_bin

# Each scenario starts a server, prints a line once it runs, then waits to be killed. Argument 1: a
# folder of its own (also its TMPDIR); argument 2: "handler" to run inside exit_on_sigterm(), as
# the benchmarks do.
PREAMBLE = """
import contextlib, sys, time
from pathlib import Path
from harness import servers
data, mode = Path(sys.argv[1]), sys.argv[2]
with servers.exit_on_sigterm() if mode == "handler" else contextlib.nullcontext():
"""
SCENARIOS = {
    "serve_app": """
    env = {"SWEEPCAST_DATA_DIR": str(data / "data"), "SWEEPCAST_DEMO_RIG": "false"}
    with servers.serve_app(env, log=data / "server.log") as app:
        print(app.proc.pid, flush=True)
        time.sleep(600)
""",
    "ray_cluster": """
    with servers.ray_cluster(worker_nodes=1) as address:
        print(address, flush=True)
        time.sleep(600)
""",
    "temp_postgres": """
    with servers.temp_postgres() as url:
        print(url, flush=True)
        time.sleep(600)
""",
}


def _stat(pid: int) -> tuple[int, int] | None:
    """(parent pid, process group) of a live process; None when it is gone or a zombie."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return None if fields[0] == "Z" else (int(fields[1]), int(fields[2]))


def _running() -> dict[int, tuple[int, int]]:
    found = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and (stat := _stat(int(entry.name))) is not None:
            found[int(entry.name)] = stat
    return found


def _own(root: int, folder: Path) -> set[int]:
    """The processes ``root`` started: its descendants, and what mentions ``folder`` (daemons)."""
    procs = _running()
    tree, grew = {root}, True
    while grew:
        more = {pid for pid, (ppid, _) in procs.items() if ppid in tree} - tree
        tree |= more
        grew = bool(more)
    mentioning = set()
    for pid in procs:
        try:
            if str(folder) in Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace"):
                mentioning.add(pid)
        except OSError:
            pass
    return (tree | mentioning) - {root}


def _left(pids: set[int], root: int, folder: Path) -> set[int]:
    """Which of ``pids`` still run, plus anything new that mentions ``folder``."""
    procs = _running()
    return {p for p in pids if p in procs} | (_own(root, folder) - {os.getpid()})


@pytest.fixture
def folder():
    # Short and readable by all: Ray's socket paths must fit 107 bytes, and PostgreSQL runs as
    # 'postgres' when the tests run as root.
    path = Path(tempfile.mkdtemp(prefix="sc-", dir="/tmp"))
    path.chmod(0o755)
    yield path
    shutil.rmtree(path, ignore_errors=True)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("server, how", [
    ("serve_app", "sigterm-handler"), ("serve_app", "sigkill"),
    ("ray_cluster", "sigkill"), ("temp_postgres", "sigkill"),
])
def test_a_dying_starter_leaves_no_server_process(folder, server, how):
    if server == "temp_postgres" and not postgres_bin("initdb"):
        pytest.skip("no PostgreSQL binaries")
    code = PREAMBLE + SCENARIOS[server]
    starter = subprocess.Popen([sys.executable, "-c", code, str(folder), how.split("-")[-1]], cwd=ROOT,
                               env={**os.environ, "TMPDIR": str(folder)}, stdout=subprocess.PIPE, text=True)
    try:
        line = starter.stdout.readline()  # the server is up (the service: /readyz answered, Ray runs)
        assert line.strip(), (folder / "server.log").read_text()[-3000:] if (folder / "server.log").exists() else ""
        time.sleep(1.0)
        own = _own(starter.pid, folder)  # the server, what it started, the watchdog
        assert len(own) >= 2, own  # at least the watchdog and the server
        starter.send_signal(signal.SIGTERM if how.startswith("sigterm") else signal.SIGKILL)
        assert starter.wait(60) == (143 if how.startswith("sigterm") else -signal.SIGKILL)
        deadline = time.monotonic() + 60
        while _left(own, starter.pid, folder) and time.monotonic() < deadline:
            time.sleep(0.5)
        left = _left(own, starter.pid, folder)
        assert not left, {p: Path(f"/proc/{p}/cmdline").read_bytes()[:150] for p in left}
    finally:
        if starter.poll() is None:
            starter.kill()
            starter.wait()
