"""Optional third-party models: fetched and verified before use, found by the service once installed."""
import asyncio
import dataclasses
import hashlib
import http.server
import os
import threading
from pathlib import Path

import pytest

from app.cli import main as cli
from app.main import fetch_missing_models
from app.routers.photos import orientation_config
from app.settings import Settings
from workers.common.models import YUNET, ModelError, ModelFile, install, installed

SHARED_YUNET = Path(os.environ.get("SWEEPCAST_DATA", "../shared/data")).parent / "models" / "yunet" / YUNET.filename


def fake_model(payload: bytes) -> ModelFile:
    return ModelFile("fake", "fake.onnx", "http://127.0.0.1:9/none", hashlib.sha256(payload).hexdigest(),
                     len(payload), "test", "tests")


@pytest.fixture
def http_root(tmp_path):
    """A local HTTP server over ``tmp_path/www``: (folder, base URL)."""
    root = tmp_path / "www"
    root.mkdir()
    handler = lambda *a, **k: http.server.SimpleHTTPRequestHandler(*a, directory=str(root), **k)  # noqa: E731
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield root, f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


def test_a_model_is_installed_from_a_url_only_when_its_checksum_matches(tmp_path, http_root):
    root, base = http_root
    payload = os.urandom(5000)
    (root / "good.onnx").write_bytes(payload)
    (root / "bad.onnx").write_bytes(payload[:-1] + bytes([payload[-1] ^ 1]))
    model = fake_model(payload)
    data = tmp_path / "data"

    path = install(model, data, f"{base}/good.onnx")
    assert path == installed(model, data) and path.read_bytes() == payload

    with pytest.raises(ModelError, match="checksum mismatch"):
        install(model, data, f"{base}/bad.onnx")
    with pytest.raises(ModelError, match="cannot read"):
        install(model, data, f"{base}/missing.onnx")
    assert path.read_bytes() == payload  # the installed copy survives failed attempts
    assert sorted(p.name for p in path.parent.iterdir()) == ["fake.onnx"]  # no temporary files left


def test_a_source_longer_than_the_model_is_cut_off(tmp_path):
    payload = b"x" * 100
    source = tmp_path / "long.bin"
    source.write_bytes(payload * 50)
    with pytest.raises(ModelError, match="larger than"):
        install(fake_model(payload), tmp_path / "data", source)
    assert installed(fake_model(payload), tmp_path / "data") is None


def test_the_service_uses_an_installed_yunet_unless_a_setting_names_another(tmp_path, monkeypatch):
    monkeypatch.delenv("SWEEPCAST_ORIENTATION_YUNET_MODEL", raising=False)
    payload = b"not really a network"
    model = dataclasses.replace(YUNET, sha256=hashlib.sha256(payload).hexdigest(), size=len(payload))
    source = tmp_path / "model.onnx"
    source.write_bytes(payload)
    settings = Settings(data_dir=tmp_path / "data")
    assert orientation_config(settings).yunet_model is None
    install(model, settings.data_dir, source)
    assert orientation_config(settings).yunet_model == settings.data_dir / "models" / YUNET.filename
    other = tmp_path / "elsewhere.onnx"
    assert orientation_config(Settings(data_dir=tmp_path / "data", orientation_yunet_model=other)).yunet_model == other


def test_cli_refuses_a_file_that_is_not_the_pinned_model(tmp_path, capsys):
    wrong = tmp_path / "wrong.onnx"
    wrong.write_bytes(b"\0" * YUNET.size)
    assert cli(["models", "fetch", "yunet", "--from", str(wrong), "--data-dir", str(tmp_path)]) == 1
    assert "checksum mismatch" in capsys.readouterr().err
    assert installed(YUNET, tmp_path) is None
    assert cli(["models", "fetch", "nosuch", "--data-dir", str(tmp_path)]) == 2


@pytest.mark.skipif(not SHARED_YUNET.is_file(), reason=f"no YuNet copy at {SHARED_YUNET}")
def test_cli_installs_the_real_yunet_and_lists_it(tmp_path, capsys):
    assert cli(["models", "fetch", "yunet", "--from", str(SHARED_YUNET), "--data-dir", str(tmp_path)]) == 0
    assert installed(YUNET, tmp_path).read_bytes() == SHARED_YUNET.read_bytes()
    capsys.readouterr()
    assert cli(["models", "list", "--data-dir", str(tmp_path)]) == 0
    assert "installed at" in capsys.readouterr().out
    # already there: --if-missing does not touch the network
    assert cli(["models", "fetch", "--if-missing", "--data-dir", str(tmp_path)]) == 0


def test_the_service_fetches_missing_models_at_start_and_goes_on_when_it_cannot(tmp_path, http_root, monkeypatch,
                                                                                 caplog):
    root, base = http_root
    payload = os.urandom(3000)
    (root / "m.onnx").write_bytes(payload)
    good = dataclasses.replace(fake_model(payload), name="good", url=f"{base}/m.onnx")
    gone = dataclasses.replace(fake_model(payload), name="gone", filename="gone.onnx", url=f"{base}/missing.onnx")
    monkeypatch.setattr("app.main.MODELS", {"good": good, "gone": gone})
    settings = Settings(data_dir=tmp_path / "data")

    asyncio.run(fetch_missing_models(settings.model_copy(update={"fetch_models": False})))
    assert installed(good, settings.data_dir) is None  # off: nothing fetched
    asyncio.run(fetch_missing_models(settings))
    assert installed(good, settings.data_dir).read_bytes() == payload
    assert installed(gone, settings.data_dir) is None
    assert "optional model gone not installed" in caplog.text
