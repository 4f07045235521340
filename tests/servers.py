"""Throw-away servers on loopback for tests and benchmarks: PostgreSQL and a Ray cluster."""
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
