"""Shared fixtures: one local Ray for the whole run, apps on temporary data folders."""
from __future__ import annotations

import os

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
os.environ.setdefault("RAY_AUTH_MODE", "disabled")
# The loopback S3 server takes any credentials; set them before Ray starts so its workers see them too.
os.environ.setdefault("AWS_ACCESS_KEY_ID", "sweepcast-test")
os.environ.setdefault("AWS_SECRET_ACCESS_KEY", "sweepcast-test")
# One kernel cache and one model cache for the run, its servers and their Ray workers: the checkout's (a fresh clone
# compiles its kernels and builds its models once, as CI does, and never reads or fills the user's caches the service
# defaults to); no background warm-up competing for the CPU.
os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                                      "sweepcast-data", "cache", "numba"))
os.environ.setdefault("SWEEPCAST_MODEL_CACHE_DIR", os.path.join(os.path.dirname(os.path.dirname(
    os.path.abspath(__file__))), "sweepcast-data", "cache", "models"))  # the models built here (the word lists)
os.environ.setdefault("SWEEPCAST_WARM_KERNELS", "false")
os.environ.setdefault("SWEEPCAST_WARM_WORKERS", "false")

import pytest  # noqa: E402


WARM_BESIDE_THE_TESTS_MIN_ITEMS = 100
"""A run of at least this many tests compiles the kernels beside them (below); a few selected tests do not."""


def pytest_configure(config):
    """A parallel run (``-n N``, pytest-xdist, as ``make test`` runs the suite) compiles every engine's kernels
    first, in the controller, one process per test worker: otherwise each worker compiles the same kernels on
    its own critical path (a fresh clone's minutes, twice over). A serial run compiles them beside the tests."""
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return
    import subprocess
    import sys
    from pathlib import Path

    from workers.warmup import is_current

    cache = Path(os.environ["NUMBA_CACHE_DIR"])
    if is_current(cache):
        return
    cache.mkdir(parents=True, exist_ok=True)
    jobs = max(1, min(int(config.option.numprocesses), os.cpu_count() or 1))
    subprocess.run([sys.executable, "-m", "workers.warmup", "--jobs", str(jobs)], stdin=subprocess.DEVNULL,
                   stdout=subprocess.DEVNULL, check=True)


@pytest.fixture(scope="session", autouse=True)
def _kernels_compiled_beside_the_tests(request):
    """Every engine's kernels compiled into the run's cache by one low-priority process while the tests run, unless
    a full warm-up already stamped it for this code. Many tests wait on Ray, servers and subprocesses and leave a
    core idle; without this, each kernel is compiled on the tests' critical path by the first test (or its Ray
    worker) that needs it: minutes of a fresh clone's run. A test that needs a kernel still compiling compiles it
    itself, as before."""
    import signal
    import subprocess
    import sys
    from pathlib import Path

    from workers.common.spawn import niced
    from workers.warmup import is_current

    cache = Path(os.environ["NUMBA_CACHE_DIR"])
    if len(request.session.items) < WARM_BESIDE_THE_TESTS_MIN_ITEMS or is_current(cache):
        yield
        return
    cache.mkdir(parents=True, exist_ok=True)
    proc = subprocess.Popen(niced([sys.executable, "-m", "workers.warmup", "--jobs", "1"], 19),
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        yield
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


@pytest.fixture(autouse=True)
def _user_cache_in_tmp(tmp_path, monkeypatch):
    """Each test's own user cache (the service keeps its demo recording there by default): tests never write into
    the home folder, and no test sees a recording another test kept."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "user-cache"))


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
        # No demo rig unless a test asks: building it costs seconds of CPU at every start.
        values = {"data_dir": tmp_path / "data", "job_lease_seconds": 5.0, "demo_rig": False, "fetch_models": False, **overrides}
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


def _postgres_or_skip(start):
    """What ``start()`` (a context manager of harness.servers) yields, for a fixture; the test skipped where no
    PostgreSQL binaries exist."""
    from harness.servers import Unavailable

    try:
        with start() as server:
            yield server
    except Unavailable as exc:
        pytest.skip(str(exc))


@pytest.fixture(scope="session")
def postgres_server():
    """A throw-away PostgreSQL cluster on loopback for this test run (its URL)."""
    from harness.servers import temp_postgres

    yield from _postgres_or_skip(temp_postgres)


@pytest.fixture
def stoppable_postgres():
    """A PostgreSQL server of this test's own, which it may stop and start (the session's is shared: never stopped)."""
    from harness.servers import postgres_server as own_postgres_server

    yield from _postgres_or_skip(own_postgres_server)


@pytest.fixture
def postgres_url(postgres_server):
    """A fresh, empty database on the test PostgreSQL server."""
    import uuid

    from harness.servers import create_database

    return create_database(postgres_server, f"t_{uuid.uuid4().hex[:12]}")


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
