"""The local Ray cluster keeps the workers a batch job's blocks ran in, so that the next library finds them started."""
import sys
import types

from app import raycluster
from app.settings import Settings


def test_the_idle_workers_kept_are_twice_the_cpus_and_two_at_most_eight_more_unless_set(monkeypatch):
    assert raycluster.idle_worker_limit(2) == 6
    assert raycluster.idle_worker_limit(16) == 24
    assert raycluster.idle_worker_limit(2, 3) == 3
    monkeypatch.setattr(raycluster, "usable_cores", lambda: 3)  # no CPU count given: the cores this process may use
    assert raycluster.idle_worker_limit(None) == 8


def test_a_local_cluster_is_started_with_that_limit_and_a_real_cluster_keeps_its_own(monkeypatch):
    calls: list[dict] = []
    fake = types.SimpleNamespace(is_initialized=lambda: False, cluster_resources=lambda: {},
                                 init=lambda **kwargs: calls.append(kwargs))
    monkeypatch.setitem(sys.modules, "ray", fake)
    assert raycluster.connect(None, 2) is True
    assert calls[-1]["_system_config"] == {"num_workers_soft_limit": 6}
    assert raycluster.connect(None, 2, idle_workers=3) is True
    assert calls[-1]["_system_config"] == {"num_workers_soft_limit": 3}
    assert raycluster.connect("head:6379", None) is True
    assert calls[-1]["address"] == "head:6379" and "_system_config" not in calls[-1]


def test_the_setting_reaches_the_local_cluster(monkeypatch, tmp_path):
    seen: list[tuple] = []
    monkeypatch.setattr(raycluster, "connect", lambda *args: seen.append(args) or True)
    monkeypatch.setenv("SWEEPCAST_RAY_IDLE_WORKERS", "5")
    assert raycluster.connect_for(Settings(data_dir=tmp_path)) is True
    assert seen[0][3] == 5
