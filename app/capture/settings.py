"""Settings of ``sweepcast live`` (environment ``SWEEPCAST_LIVE_*``; each also a command-line option)."""
from __future__ import annotations

from typing import Literal

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict


class CaptureSettings(BaseSettings):
    """What the capture side waits for, keeps and sends. Times in seconds unless a name says otherwise."""

    model_config = SettingsConfigDict(env_prefix="SWEEPCAST_LIVE_", extra="ignore")

    tolerance_ms: float | None = Field(None, gt=0, le=1000, description="Largest spread of capture times within one "
                                       "frame set (latest minus earliest), in ms; default half the frame period of "
                                       "the slowest camera.")
    missing_seconds: float = Field(1.0, gt=0, le=60, description="A camera with no new frame for this long is "
                                   "reported missing, and sets go on with its last frame marked stale (left out of "
                                   "the render); until then sets wait for it.")
    open_timeout_seconds: float = Field(5.0, gt=0, le=120, description="A source that does not open within this long "
                                        "(no answer, no stream) is reported and tried again.")
    read_timeout_seconds: float = Field(5.0, gt=0, le=120, description="A source that sends nothing for this long is "
                                        "reported as stopped and reconnected.")
    max_backoff_seconds: float = Field(2.0, gt=0, le=300, description="Longest wait between two attempts to reopen a "
                                       "source (the waits double from 0.25 s up to this).")
    keep_frames: int = Field(8, ge=2, le=64, description="Newest decoded frames kept per camera to choose sets from; "
                             "older ones are dropped (a slow consumer never builds up lag).")
    jpeg_quality: int = Field(90, ge=30, le=100, description="JPEG quality of the frames sent to the service.")
    rtsp_transport: Literal["tcp", "udp"] = Field("tcp", description="RTSP over the RTSP connection (tcp: no loss, "
                                                  "passes firewalls) or over UDP.")
    in_flight: int = Field(2, ge=1, le=16, description="Frame sets sent and not yet acknowledged by the service; past "
                           "it the newest set waits and older ones are dropped.")
    drift_window_seconds: float = Field(10.0, gt=0, le=600, description="Window of the arrival-anchored clock: the "
                                        "least-delayed frame of this window anchors a stream's own timestamps (tracks "
                                        "drift between the camera's clock and ours).")
