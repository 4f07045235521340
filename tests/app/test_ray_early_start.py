"""`sweepcast serve` starts connecting to Ray before it imports the service; the lifespan then waits
for that start instead of starting a second one."""
import threading

import pytest

from app import raycluster
from app.settings import Settings


@pytest.fixture
def fake_connect(monkeypatch):
    calls: list[tuple] = []
    release = threading.Event()

    def connect(address, num_cpus=None, env=None, idle_workers=None):
        calls.append((address, num_cpus, threading.current_thread().name))
        release.wait(10)
        if address == "ray://unreachable":
            raise ConnectionError("no cluster at ray://unreachable")
        return True

    monkeypatch.setattr(raycluster, "connect", connect)
    monkeypatch.setattr(raycluster, "_early", None)
    return calls, release


def test_the_lifespan_waits_for_the_early_start_instead_of_starting_again(tmp_path, fake_connect):
    calls, release = fake_connect
    settings = Settings(data_dir=tmp_path)
    raycluster.start_connecting(settings)
    release.set()
    assert raycluster.connect_for(settings) is True
    assert len(calls) == 1 and calls[0][2].startswith("ray-connect")  # on the long-lived connect thread


def test_other_settings_connect_on_their_own(tmp_path, fake_connect):
    calls, release = fake_connect
    release.set()
    early = Settings(data_dir=tmp_path)
    raycluster.start_connecting(early)
    assert raycluster.connect_for(Settings(data_dir=tmp_path / "other")) is True
    assert raycluster.connect_for(early) is True
    assert len(calls) == 2 and sum(c[2].startswith("ray-connect") for c in calls) == 1


def test_an_early_start_that_fails_reports_its_error_to_the_lifespan(tmp_path, fake_connect):
    _, release = fake_connect
    settings = Settings(data_dir=tmp_path, ray_address="ray://unreachable")
    raycluster.start_connecting(settings)
    release.set()
    with pytest.raises(ConnectionError, match="unreachable"):
        raycluster.connect_for(settings)
