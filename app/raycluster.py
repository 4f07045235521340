"""Connecting to Ray: a local cluster by default, an existing one when an address is set."""
from __future__ import annotations

import logging
import os
import tempfile
from typing import Any

log = logging.getLogger("sweepcast.ray")


def connect(address: str | None, num_cpus: int | None = None, env: dict[str, str] | None = None) -> bool:
    """Initialise Ray in this process; return True when this call started it (and so owns it).

    The embedded default starts a local cluster on loopback without the dashboard, with Ray's
    token authentication off (it listens on loopback only). A real cluster keeps its own
    security settings: see the README's scale-out section for the token. ``env`` is set on
    every worker process that runs this service's tasks.
    """
    import ray

    if ray.is_initialized():
        return False
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    kwargs: dict[str, Any] = {"ignore_reinit_error": True, "log_to_driver": True}
    if env:
        kwargs["runtime_env"] = {"env_vars": dict(env)}
    if address:
        ray.init(address=address, **kwargs)
    else:
        os.environ.setdefault("RAY_AUTH_MODE", "disabled")
        temp_dir = os.path.join(tempfile.gettempdir(), "sweepcast-ray")
        ray.init(num_cpus=num_cpus, include_dashboard=False, _temp_dir=temp_dir, **kwargs)
    log.info("Ray ready: %s", ray.cluster_resources())
    return True


def ready() -> tuple[bool, str]:
    """Whether Ray answers, and a short reason."""
    try:
        import ray

        if not ray.is_initialized():
            return False, "Ray is not connected yet"
        nodes = [n for n in ray.nodes() if n.get("Alive")]
        if not nodes:
            return False, "no live Ray node"
        return True, f"{len(nodes)} Ray node(s)"
    except Exception as exc:  # noqa: BLE001 - readiness reports, it never raises
        return False, f"Ray unreachable: {type(exc).__name__}: {exc}"
