"""Throw-away servers on loopback for tests and benchmarks: PostgreSQL, a Ray cluster and the service itself."""
from __future__ import annotations

import contextlib
import glob
import os
import pwd
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator


class Unavailable(RuntimeError):
    """The server cannot be started on this machine (the message says why)."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def postgres_bin(name: str) -> str | None:
    found = shutil.which(name)
    if found:
        return found
    candidates = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"))
    return candidates[-1] if candidates else None


@contextlib.contextmanager
def temp_postgres() -> Iterator[str]:
    """A PostgreSQL cluster in a temp dir (initdb + pg_ctl); yields ``postgresql://sweepcast@127.0.0.1:PORT``."""
    initdb, pg_ctl = postgres_bin("initdb"), postgres_bin("pg_ctl")
    if not initdb or not pg_ctl:
        raise Unavailable("no PostgreSQL binaries (initdb, pg_ctl): install Debian's postgresql package")
    base = Path(tempfile.mkdtemp(prefix="sweepcast-pg-"))  # not below a root-only temp folder
    data, sockets = base / "data", base / "sock"
    sockets.mkdir()
    prefix: list[str] = []
    if os.geteuid() == 0:  # PostgreSQL refuses to run as root
        try:
            user = pwd.getpwnam("postgres")
        except KeyError:
            shutil.rmtree(base, ignore_errors=True)
            raise Unavailable("running as root and there is no 'postgres' user to run PostgreSQL as") from None
        for path in (base, sockets):
            shutil.chown(path, user.pw_uid, user.pw_gid)
        prefix = ["runuser", "-u", "postgres", "--"]
    port = free_port()
    try:
        subprocess.run([*prefix, initdb, "-D", str(data), "-U", "sweepcast", "--auth=trust", "--no-sync", "-E", "UTF8"],
                       check=True, capture_output=True)
        subprocess.run([*prefix, pg_ctl, "-D", str(data), "-l", str(base / "log"), "-w", "-t", "60", "start",
                        "-o", f"-p {port} -k {sockets} -c listen_addresses=127.0.0.1 -c fsync=off"],
                       check=True, capture_output=True)
        yield f"postgresql://sweepcast@127.0.0.1:{port}"
    finally:
        subprocess.run([*prefix, pg_ctl, "-D", str(data), "-m", "immediate", "stop"], capture_output=True)
        shutil.rmtree(base, ignore_errors=True)


def create_database(server_url: str, name: str) -> str:
    """Create database ``name`` on ``server_url`` and return its URL."""
    import sqlalchemy

    admin = sqlalchemy.create_engine(server_url.replace("postgresql://", "postgresql+psycopg://") + "/postgres",
                                     isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.exec_driver_sql(f'CREATE DATABASE "{name}"')
    admin.dispose()
    return f"{server_url}/{name}"


def processes_mentioning(text: str) -> list[int]:
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if text in (entry / "cmdline").read_bytes().decode(errors="replace"):
                    pids.append(int(entry.name))
            except OSError:
                pass
    return pids


@contextlib.contextmanager
def ray_cluster(worker_nodes: int = 2, cpus_per_node: int = 1, resources: str = '{"sweepcast_worker": 1}'
                ) -> Iterator[str]:
    """A Ray head without task CPUs plus ``worker_nodes`` nodes, as `ray start` makes them; yields its address."""
    temp = tempfile.mkdtemp(prefix="scray-")  # short: Ray's socket paths must fit 107 bytes
    port = free_port()
    env = {**os.environ, "RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0"}
    ray = str(Path(sys.executable).parent / "ray")
    common = [f"--temp-dir={temp}", "--disable-usage-stats"]
    try:
        subprocess.run([ray, "start", "--head", f"--port={port}", "--num-cpus=0", "--include-dashboard=false",
                        *common], check=True, capture_output=True, env=env, timeout=120)
        for _ in range(worker_nodes):
            subprocess.run([ray, "start", f"--address=127.0.0.1:{port}", f"--num-cpus={cpus_per_node}",
                            f"--resources={resources}", *common], check=True, capture_output=True, env=env,
                           timeout=120)
        yield f"127.0.0.1:{port}"
    finally:
        for pid in processes_mentioning(temp):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        shutil.rmtree(temp, ignore_errors=True)


ROOT = Path(__file__).resolve().parents[1]


@dataclass
class ServedApp:
    """``python -m app serve`` running as a child process."""

    base: str
    """http://127.0.0.1:<port>"""
    proc: subprocess.Popen
    log: Path | None

    def log_tail(self, chars: int = 3000) -> str:
        return self.log.read_text(errors="replace")[-chars:] if self.log is not None and self.log.exists() else ""

    def wait_ready(self, timeout: float = 180.0) -> None:
        """Until ``/readyz`` answers 200; RuntimeError (with the log's tail) when the server exits or is late."""
        import httpx

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"the server exited with code {self.proc.returncode}; log: {self.log_tail()}")
            try:
                if httpx.get(f"{self.base}/readyz", timeout=2.0).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.25)
        raise RuntimeError(f"the server was not ready after {timeout:.0f} s; log: {self.log_tail()}")


@contextlib.contextmanager
def serve_app(env: dict[str, str | None], log: Path | None = None, args: tuple[str, ...] = (), wait: bool = True,
              ready_timeout: float = 180.0) -> Iterator[ServedApp]:
    """Run the service on a free port with ``env`` over this environment (None removes a variable; model
    fetching and Ray usage stats off), its output to ``log`` (else discarded); wait for ``/readyz`` unless
    ``wait`` is False; stop it (terminate, then kill after 30 s) on leaving."""
    port = free_port()
    merged = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "SWEEPCAST_FETCH_MODELS": "false", **env}
    env = {k: v for k, v in merged.items() if v is not None}
    out = open(log, "wb") if log is not None else subprocess.DEVNULL
    proc = subprocess.Popen([sys.executable, "-m", "app", "serve", "--port", str(port), *args], cwd=ROOT, env=env,
                            stdout=out, stderr=subprocess.STDOUT)
    try:
        app = ServedApp(f"http://127.0.0.1:{port}", proc, log)
        if wait:
            app.wait_ready(ready_timeout)
        yield app
    finally:
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if log is not None:
            out.close()
