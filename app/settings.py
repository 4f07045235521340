"""Service settings, read from the environment (prefix ``SWEEPCAST_``) or a ``.env`` file."""
from __future__ import annotations

import os
from functools import cached_property
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, field_validator
from pydantic_settings import NoDecode, SettingsConfigDict

from workers.portable_cache import SHIPPED_KERNELS, STAMP_NAME
from workers.common.safezip import ZipLimits
from workers.settings import WorkerSettings

MiB = 1 << 20


def user_cache_dir() -> Path:
    """This user's cache of what the service builds once per machine and code, whatever the data folder:
    ``$XDG_CACHE_HOME/sweepcast``, else ``~/.cache/sweepcast``."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "sweepcast"
DEFAULT_VIEWER_SIZE = "400x300"
"""The browser viewer's starting size (benchmarks/RESULTS.md, streaming_viewer_size: one viewer of the demo
rig at 20 fps or more on 2 cores)."""


class Settings(WorkerSettings):
    """The service's settings: its own and every worker setting (:class:`workers.settings.WorkerSettings`:
    image, video, zip and dense limits, the orientation engine's tools and models), passed on to its workers."""

    model_config = SettingsConfigDict(env_prefix="SWEEPCAST_", env_file=".env", extra="ignore")

    data_dir: Path = Field(Path("./sweepcast-data"), description="Blob store, SQLite file and Ray temp files.")
    database_url: str | None = Field(None, description="SQLAlchemy URL; default SQLite inside data_dir.")
    storage_url: str | None = Field(None, description="Blob store URL; default file://<data_dir>/blobs.")
    ray_address: str | None = Field(None, description="Existing Ray cluster (host:port or ray://...); default: start a local one.")
    ray_num_cpus: int | None = Field(None, ge=1, description="CPUs of the local Ray cluster (default: all).")
    ray_idle_workers: int | None = Field(None, ge=1, description="Worker processes the local Ray cluster keeps "
                                         "when idle (default: twice its CPUs and two, at most its CPUs + 8). A "
                                         "batch job's own task waits in one worker while its blocks run in others: "
                                         "Ray's default (one per CPU) ended those others after each library, and the "
                                         "next library started them again (2-3 s of CPU each: imports, detectors).")
    ray_join_node: bool = Field(False, description="With ray_address: first join the cluster as a node without CPUs "
                                "(`ray start --address --num-cpus=0`: the local raylet a driver needs), while the service "
                                "imports itself; the Docker image's API role sets it. When the join fails (the head is "
                                "unreachable) the process exits with code 3, for its supervisor to start it again.")
    host: str = "127.0.0.1"
    port: int = Field(8000, ge=1, le=65535)
    api_keys: Annotated[list[str], NoDecode] = Field(default_factory=list, description="Comma-separated bearer keys "
                                                     "that act as admin (they see everything); managed keys are made with "
                                                     "`sweepcast keys create`. No keys of either kind: no auth.")
    quota_stored_bytes: int = Field(20 * 1024 * MiB, ge=1, description="Bytes a user key may keep stored (its jobs' "
                                    "uploads and results, recordings included); a key's own quota overrides it.")
    quota_active_jobs: int = Field(8, ge=1, description="Jobs a user key may have queued or running at once.")
    quota_viewer_sessions: int = Field(4, ge=1, description="Viewer sockets a user key may hold open on one API replica.")
    quota_uploads_per_minute: int = Field(60, ge=1, description="Uploads (POSTs with files) a user key may send per "
                                          "minute to one API replica.")

    min_free_storage_mb: float = Field(256.0, ge=0, description="/readyz reports not ready when the data folder "
                                       "(a file blob store) has less free space than this (megabytes).")
    header_timeout_seconds: float = Field(20.0, gt=0, description="A request whose headers have not all arrived "
                                          "this long after its connection opened (or its first byte, on a "
                                          "kept-alive connection) is answered 408 and closed.")
    upload_idle_seconds: float = Field(60.0, gt=0, description="A request body with no bytes for this long is cut "
                                       "off (408).")
    min_upload_bytes_per_second: float = Field(1024.0, ge=0, description="After its first minute, a request body "
                                               "slower than this on average is cut off (408).")
    max_upload_bytes: int = Field(64 * MiB, ge=1, description="Largest request body of single-file endpoints.")
    max_batch_bytes: int = Field(1024 * MiB, ge=1, description="Largest request body of batch uploads.")
    max_json_bytes: int = Field(1 * MiB, ge=1, description="Largest request body of routes that take JSON (or no body).")
    max_batch_files: int = Field(500, ge=1, description="Most files in one batch upload.")
    request_threads: int | None = Field(None, ge=1, description="Threads for per-request image work in the API process (default: one per core).")
    sync_max_cpu_seconds: float = Field(10.0, gt=0, description="Most CPU-seconds one synchronous depth request "
                                        "(filter, synthesize) may take in the API process, estimated from its sizes "
                                        "and parameters before decoding; over it: 413 (send it as a job).")
    sync_max_memory_mb: float = Field(1024.0, gt=0, description="Most memory one synchronous depth request may hold "
                                      "(megabytes, estimated before decoding); over it: 413.")
    sync_memory_budget_mb: float = Field(2048.0, gt=0, description="Estimated memory of all synchronous depth "
                                         "requests and face transforms running at once in one API process "
                                         "(megabytes); others wait.")
    sync_wait_seconds: float = Field(10.0, ge=0, description="How long such a request waits for room in "
                                     "sync_memory_budget_mb before it is answered 503 with Retry-After.")

    job_max_attempts: int = Field(3, ge=1, le=10, description="Attempts per job when a worker is lost.")
    job_lease_seconds: float = Field(30.0, gt=0, description="A running job whose lease is this old is resubmitted.")
    job_resources: dict[str, float] = Field(default_factory=dict, description="Custom Ray resources every batch job requires (JSON).")
    job_unschedulable_seconds: float = Field(120.0, gt=0, description="Fail a job when no live Ray node offers its resources for this long.")

    fetch_models: bool = Field(True, description="At start-up, download the optional models that are missing (YuNet) "
                                                 "into <data_dir>/models, checked by SHA-256; offline, log it and go on.")
    numba_cache_dir: Path | None = Field(
        None, description="Where the compiled numba kernels are kept (the service and its workers): default "
                          "NUMBA_CACHE_DIR when set, else this user's cache (~/.cache/sweepcast/kernels), shared by "
                          "every data folder and every install of the same sources. numba keys each entry by the "
                          "source's hash, argument types and CPU, so one directory serves every CPU kind that shares "
                          "it.")
    prebuilt_kernels: Path | None = Field(
        None, description="A kernel cache compiled ahead for a portable CPU target (`sweepcast warmup --target "
                          "x86-64-v3`, e.g. in the Docker image; read-only is fine): when this CPU runs that target, "
                          "the service and its workers compile for it and copy the kernels into their cache, so "
                          "nothing is compiled; else they compile for this CPU, and the log and /readyz say why. "
                          "Default: the kernels a wheel built by `make wheel` carries, when it carries them.")
    warm_kernels: bool = Field(True, description="At start-up, compile every engine's kernels into the cache in a "
                                                 "background process (`sweepcast warmup`), so that no request waits "
                                                 "for a compile; a warm cache makes it take seconds.")
    warm_workers: bool = Field(True, description="At start-up, the local Ray cluster's idle workers (ray_idle_workers) "
                                                 "import the engines and build the orientation engine in the "
                                                 "background (workers/prewarm.py), so the first photo library after "
                                                 "a start does not pay for it (2-3 s of CPU per worker process).")

    max_rig_cameras: int = Field(64, ge=2, description="Most cameras in one rig.")
    max_recording_frames: int = Field(3000, ge=1, description="Most frames per camera in one recording.")
    max_view_pixels: int = Field(1920 * 1080, ge=256, description="Largest virtual view (width x height) a viewer or batch render may ask for.")
    max_view_planes: int = Field(256, ge=2, description="Most depth planes a viewer or batch render may ask for.")
    live_max_spread_ms: float = Field(100.0, gt=0, le=10_000, description="The largest spread of capture times "
                                      "(latest minus earliest, ms) a live frame set may have, whatever tolerance its "
                                      "client declares; a set over its tolerance is refused and not shown.")
    session_idle_seconds: float = Field(60.0, gt=0, description="A virtual-view session nobody has used for this long ends.")
    session_resources: dict[str, float] = Field(default_factory=dict, description="Ray resources every session actor requires (JSON), e.g. {\"GPU\": 0.25} for a quarter of a GPU (the renderer then searches depth there) or a custom resource such as {\"renderer\": 1}.")
    session_render_slots: int = Field(1, ge=1, le=64, description="Views a session draws at once; its other viewers "
                                      "wait their turn, in arrival order (round robin, one place per viewer).")
    viewer_stall_seconds: float = Field(10.0, gt=0, le=600, description="A viewer (or live) socket that has not taken "
                                        "its frames (or any message) for this long is closed (1008 and a reason, "
                                        "one log line) and then cut off if it still reads nothing.")
    demo_rig: bool = Field(True, description="At start-up, build the procedural demo rig and its recording when there is none.")
    viewer_size: str = Field(DEFAULT_VIEWER_SIZE, pattern=r"^[1-9][0-9]{1,4}x[1-9][0-9]{1,4}$",
                             description="The view size (WIDTHxHEIGHT px) the browser viewer starts at (sent in the "
                                         "view socket's hello): the largest at which one viewer of the demo rig gets "
                                         ">= 20 fps on 2 cores (python -m benchmarks.streaming --only viewer_sizes).")
    viewer_frame_cache_mb: float = Field(256.0, ge=0, description="Encoded frame sets of recordings kept in each API "
                                         "process for viewers that render in their browser (megabytes).")
    viewer_frame_format: Literal["png", "jpeg"] = Field(
        "png", description="How recordings' frame sets travel to browser-rendering viewers: png (lossless: the view "
                           "matches the server's) or jpeg (far fewer bytes at viewer_frame_quality, a worse view: "
                           "benchmarks/RESULTS.md, streaming_browser_quality).")
    viewer_frame_quality: int = Field(90, ge=50, le=100, description="JPEG quality when viewer_frame_format is jpeg.")
    viewer_target_fps: float = Field(15.0, gt=0, le=240, description="The frame rate a viewer's 'auto' quality holds: "
                                     "the browser renders itself at the best quality level that holds it at the "
                                     "chosen view size, else falls back to server rendering (sent in the view "
                                     "socket's hello); a session draws the 'best' level where its renders hold it, "
                                     "else 'fast'.")

    @field_validator("api_keys", mode="before")
    @classmethod
    def _split_keys(cls, value: Any) -> Any:
        if isinstance(value, str):
            return [k.strip() for k in value.split(",") if k.strip()]
        return value

    @property
    def viewer_size_px(self) -> tuple[int, int]:
        """:attr:`viewer_size` as (width, height) px."""
        w, h = self.viewer_size.split("x")
        return int(w), int(h)

    @property
    def zip_limits(self) -> ZipLimits:
        """The limits of every zip archive the service reads (its workers get them as environment)."""
        return ZipLimits.from_settings(self)

    @cached_property
    def resolved_database_url(self) -> str:
        return self.database_url or f"sqlite:///{(self.data_dir / 'sweepcast.db').resolve()}"

    @property
    def resolved_numba_cache_dir(self) -> Path:
        """The kernel cache: the setting, else ``NUMBA_CACHE_DIR``, else :func:`user_cache_dir` ``/kernels`` (a new
        data folder needs no compiling: the kernels depend on the code and the CPU, not on the data)."""
        if self.numba_cache_dir is not None:
            return self.numba_cache_dir.resolve()
        if os.environ.get("NUMBA_CACHE_DIR"):
            return Path(os.environ["NUMBA_CACHE_DIR"]).resolve()
        return (user_cache_dir() / "kernels").resolve()

    @property
    def resolved_prebuilt_kernels(self) -> Path | None:
        """The kernels compiled ahead to use: the setting, else those the installed wheel carries
        (:data:`workers.portable_cache.SHIPPED_KERNELS`, stamped by its build), else None."""
        if self.prebuilt_kernels is not None:
            return self.prebuilt_kernels
        return SHIPPED_KERNELS if (SHIPPED_KERNELS / STAMP_NAME).is_file() else None

    @property
    def resolved_demo_cache_dir(self) -> Path:
        """Where the rendered demo recording is kept: the setting, else :func:`user_cache_dir` ``/demo`` (a new data
        folder's demo gets it without rendering it)."""
        return (self.demo_cache_dir or user_cache_dir() / "demo").resolve()

    @cached_property
    def resolved_storage_url(self) -> str:
        return self.storage_url or (self.data_dir / "blobs").resolve().as_uri()
