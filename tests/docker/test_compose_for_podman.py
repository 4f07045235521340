"""docker/verify/compose_for_podman.py: the compose file verify-stack.sh runs is docker/compose.yaml with only the
stated changes (Debian's postgres and redis images, no MinIO, two API replicas on their own ports, two one-CPU workers)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("compose_for_podman", ROOT / "docker/verify/compose_for_podman.py")
compose_for_podman = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(compose_for_podman)


def load() -> dict:
    return yaml.safe_load((ROOT / "docker/compose.yaml").read_text())


def test_services_are_the_compose_files_less_minio_plus_a_second_api():
    original = load()
    out = compose_for_podman.for_podman(original, 8000)
    assert set(out["services"]) == set(original["services"]) - {"minio", "minio-bucket"} | {"api-2"}
    assert out["services"]["postgres"]["image"] == "localhost/sweepcast-postgres"
    assert out["services"]["postgres"]["volumes"] == original["services"]["postgres"]["volumes"]
    assert out["services"]["redis"]["image"] == "localhost/sweepcast-redis"
    assert out["services"]["redis"]["command"] == original["services"]["redis"]["command"]
    assert "minio-bucket" not in out["services"]["api"]["depends_on"]
    assert not any(k.startswith("x-") for k in out)


def test_replicas_ports_and_worker_cpus():
    out = compose_for_podman.for_podman(load(), 9000)
    services = out["services"]
    assert services["api"]["ports"] == ["127.0.0.1:9000:8000"]
    assert services["api-2"]["ports"] == ["127.0.0.1:9001:8000"]
    assert services["api"]["volumes"] != services["api-2"]["volumes"]
    assert services["ray-worker"]["deploy"] == {"replicas": 2}
    assert services["ray-worker"]["environment"]["RAY_WORKER_CPUS"] == "1"
    assert "RAY_WORKER_CPUS" not in services["api"]["environment"]  # each service has its own environment
    assert all(s["restart"] == "on-failure" and "build" not in s for s in services.values())


def test_every_app_service_keeps_the_compose_files_environment():
    original = load()
    out = compose_for_podman.for_podman(original, 8000)
    shared = original["services"]["api"]["environment"]
    for name in ("ray-head", "ray-worker", "api", "api-2"):
        env = dict(out["services"][name]["environment"])
        env.pop("RAY_WORKER_CPUS", None)
        if name == "ray-head":  # the head alone keeps Ray's state in Redis, to come back with it after a crash
            assert env.pop("RAY_REDIS_ADDRESS") == "redis:6379"
        assert env == shared, name
