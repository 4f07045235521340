"""Write the compose file verify-stack.sh runs: docker/compose.yaml with the changes this machine needs.

    python3 docker/verify/compose_for_podman.py docker/compose.yaml OUT.yaml

Every service keeps its definition (image, command, environment, volumes, shm_size) except:
- postgres: the image built from Debian's packages (localhost/sweepcast-postgres), same variables and volume;
- redis: the image built from Debian's packages (localhost/sweepcast-redis), same command and volume;
- minio, minio-bucket: left out; the S3 stand-in runs in its own container outside the project, on the
  project's network under the name `minio`, so SWEEPCAST_STORAGE_URL is unchanged (see s3.Dockerfile);
- api: two replicas, `api` and `api-2`, published on SWEEPCAST_PORT and SWEEPCAST_PORT+1 (one host port can
  take only one container; a real deployment puts its load balancer in front);
- ray-worker: two replicas (`deploy.replicas`; podman-compose 1.0.3 ignores `--scale`), one CPU each;
- `restart: on-failure` everywhere: podman-compose 1.0.3 ignores `depends_on` conditions and podman runs no
  health checks without systemd, so a container that starts before what it needs exits and is restarted.
"""
from __future__ import annotations

import copy
import sys

import yaml


def for_podman(compose: dict, port: int) -> dict:
    """The compose document (parsed YAML) -> the one to run here (see the module docstring)."""
    out = {k: copy.deepcopy(v) for k, v in compose.items() if not k.startswith("x-")}
    services = out["services"]
    for service in services.values():  # YAML anchors share one mapping; each service gets its own
        service["environment"] = dict(service.get("environment") or {})
    for name in ("minio", "minio-bucket"):
        services.pop(name)
    services["postgres"]["image"] = "localhost/sweepcast-postgres"
    services["redis"]["image"] = "localhost/sweepcast-redis"
    services["ray-worker"]["deploy"] = {"replicas": 2}
    services["ray-worker"]["environment"]["RAY_WORKER_CPUS"] = "1"
    api = services["api"]
    api["depends_on"] = {k: v for k, v in api["depends_on"].items() if not k.startswith("minio")}
    api["ports"] = [f"127.0.0.1:{port}:8000"]
    second = copy.deepcopy(api)
    second["ports"] = [f"127.0.0.1:{port + 1}:8000"]
    second["volumes"] = ["api-data-2:/data"]
    services["api-2"] = second
    out["volumes"]["api-data-2"] = None
    out["volumes"].pop("minio")
    for service in services.values():
        service["restart"] = "on-failure"
        service.pop("build", None)  # images are built beforehand (buildah), never by podman-compose
    return out


def main() -> int:
    src, dst, port = sys.argv[1], sys.argv[2], int(sys.argv[3]) if len(sys.argv) > 3 else 8000
    with open(src) as f:
        compose = yaml.safe_load(f)
    with open(dst, "w") as f:
        yaml.safe_dump(for_podman(compose, port), f, sort_keys=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
