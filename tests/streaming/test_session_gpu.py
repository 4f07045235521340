"""Session actors on GPU nodes: the operator's share of a GPU reaches Ray as the actor's num_gpus."""
from types import SimpleNamespace

from workers.streaming import actor


def test_a_gpu_share_in_the_session_resources_reaches_ray_as_num_gpus(monkeypatch):
    """Ray hides every GPU from an actor that asks for none: the operator's {"GPU": x} must become num_gpus. A session
    that asks for resources is placed by Ray where they are free; one that asks none is pinned to a node with CPUs."""
    seen = {}
    worker_id = "ab" * 28  # a node id as Ray writes it
    monkeypatch.setattr(actor.ray, "nodes", lambda: [{"NodeID": worker_id, "Alive": True, "Resources": {"CPU": 2.0}}])
    monkeypatch.setattr(actor, "_exists", lambda name: False)

    class Recorder:
        @classmethod
        def options(cls, **kw):
            seen.update(kw)
            return cls

        @classmethod
        def remote(cls, config):
            return config

    config = SimpleNamespace(name="rig-1/live")
    assert actor.get_or_create(config, {"GPU": 0.25, "renderer": 1.0}, Recorder) is config
    assert seen["num_gpus"] == 0.25 and seen["resources"] == {"renderer": 1.0}
    assert seen["scheduling_strategy"] == "DEFAULT"
    actor.get_or_create(config, None, Recorder)
    assert seen["num_gpus"] == 0.0 and seen["resources"] == {}
    assert seen["scheduling_strategy"].node_id == worker_id and not seen["scheduling_strategy"].soft
