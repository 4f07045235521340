"""Connecting to Ray: a local cluster by default, an existing one when an address is set."""
from __future__ import annotations

import logging
import os
import tempfile
from typing import Any

from app.settings import Settings
from workers.common.models import MODELS_DIR_ENV, models_dir
from workers.common.safezip import ZIP_SETTINGS

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


def connect_for(settings: Settings) -> bool:
    """:func:`connect` as ``settings`` say, with :func:`worker_env` for the workers. Blocking."""
    return connect(settings.ray_address, settings.ray_num_cpus, worker_env(settings))


def worker_env(settings: Settings) -> dict[str, str]:
    """Settings the engines read on the workers, passed to every Ray worker of this service."""
    env = {"SWEEPCAST_MAX_IMAGE_PIXELS": str(settings.max_image_pixels),
           # OpenCV's own guard, read once when a fresh worker imports cv2: a second line behind the header check
           "OPENCV_IO_MAX_IMAGE_PIXELS": str(settings.max_image_pixels),
           "SWEEPCAST_MAX_VIDEO_FRAMES": str(settings.max_video_frames),
           "SWEEPCAST_MAX_DENSE_VOLUME": str(settings.max_dense_volume)}
    env.update({f"SWEEPCAST_{name.upper()}": str(getattr(settings, name)) for name in ZIP_SETTINGS})
    env[MODELS_DIR_ENV] = str(models_dir(settings.data_dir).resolve())  # models fetched later are found too
    if settings.orientation_yunet_model is not None:
        env["SWEEPCAST_ORIENTATION_YUNET_MODEL"] = str(settings.orientation_yunet_model.resolve())
    env["SWEEPCAST_ORIENTATION_TEXT"] = "1" if settings.orientation_text else "0"
    env["SWEEPCAST_ORIENTATION_TESSERACT"] = settings.orientation_tesseract
    env["NUMBA_CACHE_DIR"] = str(settings.resolved_numba_cache_dir)  # the kernels the warm-up compiled
    return env


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
