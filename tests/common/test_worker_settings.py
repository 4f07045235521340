"""The worker settings: one model read from SWEEPCAST_* variables, included in the service's settings and
handed to its workers, so that what the service is told holds on every worker."""
from pathlib import Path

import pytest
from pydantic import ValidationError

from app.raycluster import worker_env
from app.routers.photos import orientation_config
from app.settings import Settings
from workers.common import images
from workers.common.models import YUNET
from workers.common.safezip import ZipLimits
from workers.settings import WorkerSettings, worker_settings


def test_worker_settings_read_the_environment_when_asked(monkeypatch):
    monkeypatch.setenv("SWEEPCAST_MAX_IMAGE_PIXELS", "1234")
    monkeypatch.setenv("SWEEPCAST_ORIENTATION_TEXT", "off")
    monkeypatch.setenv("SWEEPCAST_EXIFTOOL", "/opt/exiftool")
    s = worker_settings()
    assert (s.max_image_pixels, s.orientation_text, s.exiftool) == (1234, False, "/opt/exiftool")
    assert images.max_pixels_from_env() == 1234
    monkeypatch.setenv("SWEEPCAST_MAX_IMAGE_PIXELS", "many")
    with pytest.raises(ValidationError, match="max_image_pixels"):  # a typo is an error, never the default
        worker_settings()


def test_the_service_includes_and_passes_every_worker_setting(tmp_path, monkeypatch):
    for name in WorkerSettings.model_fields:
        monkeypatch.delenv(f"SWEEPCAST_{name.upper()}", raising=False)
    settings = Settings(data_dir=tmp_path, max_zip_members=7, max_video_frames=12, orientation_text=False,
                        orientation_yunet_model=tmp_path / "y.onnx")
    assert isinstance(settings, WorkerSettings)
    env = worker_env(settings)
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    on_worker = worker_settings()  # what a Ray worker of this service reads
    assert on_worker.max_zip_members == 7 and on_worker.max_video_frames == 12
    assert on_worker.orientation_text is False and on_worker.orientation_yunet_model == tmp_path / "y.onnx"
    assert on_worker.models_dir == (tmp_path / "models").resolve()
    assert ZipLimits.from_env() == settings.zip_limits
    assert env["OPENCV_IO_MAX_IMAGE_PIXELS"] == str(settings.max_image_pixels)


def test_workers_keep_two_malloc_arenas_unless_the_operator_says_otherwise(tmp_path, monkeypatch):
    monkeypatch.delenv("MALLOC_ARENA_MAX", raising=False)
    assert worker_env(Settings(data_dir=tmp_path))["MALLOC_ARENA_MAX"] == "2"
    monkeypatch.setenv("MALLOC_ARENA_MAX", "4")
    assert worker_env(Settings(data_dir=tmp_path))["MALLOC_ARENA_MAX"] == "4"


def test_one_yunet_lookup_for_service_and_workers(tmp_path):
    folder = tmp_path / "models"
    assert WorkerSettings().yunet_model(folder) is None
    folder.mkdir()
    (folder / YUNET.filename).write_bytes(b"x")
    assert WorkerSettings().yunet_model(folder) == folder / YUNET.filename
    assert orientation_config(Settings(data_dir=tmp_path)).yunet_model == folder / YUNET.filename
    chosen = Path("/elsewhere/yunet.onnx")
    assert WorkerSettings(orientation_yunet_model=chosen).yunet_model(folder) == chosen
