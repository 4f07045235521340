"""Shared fixtures: one local Ray for the whole run, apps on temporary data folders."""
from __future__ import annotations

import os

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
os.environ.setdefault("RAY_AUTH_MODE", "disabled")
# The loopback S3 server takes any credentials; set them before Ray starts so its workers see them too.
os.environ.setdefault("AWS_ACCESS_KEY_ID", "sweepcast-test")
os.environ.setdefault("AWS_SECRET_ACCESS_KEY", "sweepcast-test")

import pytest  # noqa: E402


@pytest.fixture(scope="session")
def ray_local():
    """A local Ray cluster shared by every test that needs one (started once: it takes seconds)."""
    import ray

    from app import raycluster

    started = raycluster.connect(None, num_cpus=2)
    yield ray
    if started:
        ray.shutdown()


@pytest.fixture
def settings_factory(tmp_path):
    from app.settings import Settings

    def make(**overrides):
        values = {"data_dir": tmp_path / "data", "job_lease_seconds": 5.0, **overrides}
        return Settings(**values)

    return make


@pytest.fixture
def client_factory(ray_local, settings_factory):
    """Build a TestClient over a fresh app (its lifespan runs inside the ``with`` block)."""
    from fastapi.testclient import TestClient

    from app.main import create_app

    clients = []

    def make(**overrides):
        client = TestClient(create_app(settings_factory(**overrides)))
        client.__enter__()
        clients.append(client)
        _wait_ready(client)
        return client

    yield make
    for client in clients:
        client.__exit__(None, None, None)


def _wait_ready(client, timeout: float = 60.0) -> None:
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if client.get("/readyz").status_code == 200:
            return
        time.sleep(0.05)
    raise AssertionError(f"app not ready: {client.get('/readyz').json()}")


def _postgres_bin(name: str) -> str | None:
    import glob
    import shutil

    found = shutil.which(name)
    if found:
        return found
    candidates = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"))
    return candidates[-1] if candidates else None


@pytest.fixture(scope="session")
def postgres_server():
    """A throw-away PostgreSQL cluster on loopback for this test run (initdb + pg_ctl in a temp dir).

    Yields a URL prefix ``postgresql://sweepcast@127.0.0.1:PORT``; skipped where no binaries exist.
    """
    import pwd
    import shutil
    import socket
    import subprocess
    import tempfile
    from pathlib import Path

    initdb, pg_ctl = _postgres_bin("initdb"), _postgres_bin("pg_ctl")
    if not initdb or not pg_ctl:
        pytest.skip("no PostgreSQL binaries (initdb, pg_ctl): install Debian's postgresql package")
    base = Path(tempfile.mkdtemp(prefix="sweepcast-pg-"))  # not below pytest's root-only temp folder
    data, sockets = base / "data", base / "sock"
    sockets.mkdir()
    prefix: list[str] = []
    if os.geteuid() == 0:  # PostgreSQL refuses to run as root
        try:
            user = pwd.getpwnam("postgres")
        except KeyError:
            pytest.skip("running as root and there is no 'postgres' user to run PostgreSQL as")
        for path in (base, sockets):
            shutil.chown(path, user.pw_uid, user.pw_gid)
        prefix = ["runuser", "-u", "postgres", "--"]
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    run = lambda *args: subprocess.run([*prefix, *args], check=True, capture_output=True, text=True)  # noqa: E731
    run(initdb, "-D", str(data), "-U", "sweepcast", "--auth=trust", "--no-sync", "-E", "UTF8")
    run(pg_ctl, "-D", str(data), "-l", str(base / "log"), "-w", "-t", "60", "start",
        "-o", f"-p {port} -k {sockets} -c listen_addresses=127.0.0.1 -c fsync=off")
    try:
        yield f"postgresql://sweepcast@127.0.0.1:{port}"
    finally:
        subprocess.run([*prefix, pg_ctl, "-D", str(data), "-m", "immediate", "stop"], capture_output=True)
        shutil.rmtree(base, ignore_errors=True)


@pytest.fixture
def postgres_url(postgres_server):
    """A fresh, empty database on the test PostgreSQL server."""
    import uuid

    import sqlalchemy

    name = f"t_{uuid.uuid4().hex[:12]}"
    admin = sqlalchemy.create_engine(f"{postgres_server.replace('postgresql://', 'postgresql+psycopg://')}/postgres",
                                     isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.exec_driver_sql(f'CREATE DATABASE "{name}"')
    admin.dispose()
    return f"{postgres_server}/{name}"


@pytest.fixture(scope="session")
def s3_endpoint():
    """A real S3 API server on loopback (moto's standalone server) for this test run."""
    import shutil
    import socket
    import subprocess
    import sys
    import time
    import urllib.request
    from pathlib import Path

    server = shutil.which("moto_server", path=str(Path(sys.executable).parent)) or shutil.which("moto_server")
    if server is None:
        pytest.skip("moto_server is not installed (pip install 'moto[server]')")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([server, "-H", "127.0.0.1", "-p", str(port)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 30
    while True:
        try:
            urllib.request.urlopen(url + "/moto-api/", timeout=1)
            break
        except OSError:
            if time.monotonic() > deadline or proc.poll() is not None:
                proc.kill()
                pytest.fail("moto_server did not start")
            time.sleep(0.1)
    try:
        yield url
    finally:
        proc.terminate()
        proc.wait(10)


@pytest.fixture
def s3_url(s3_endpoint):
    """A storage URL for a fresh bucket on the loopback S3 server."""
    import uuid

    import boto3

    bucket = f"b{uuid.uuid4().hex[:12]}"
    boto3.client("s3", endpoint_url=s3_endpoint, region_name="us-east-1").create_bucket(Bucket=bucket)
    return f"s3://{bucket}/sweepcast?endpoint_url={s3_endpoint}&region=us-east-1"
