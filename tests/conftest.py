"""Shared fixtures: one local Ray for the whole run, apps on temporary data folders."""
from __future__ import annotations

import os

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
os.environ.setdefault("RAY_AUTH_MODE", "disabled")

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
