"""Session actors on GPU nodes: the operator's share of a GPU reaches Ray as the actor's num_gpus."""
from types import SimpleNamespace

from workers.streaming import actor


def test_a_gpu_share_in_the_session_resources_reaches_ray_as_num_gpus(monkeypatch):
    """Ray hides every GPU from an actor that asks for none: the operator's {"GPU": x} must become num_gpus, and
    the actor is placed on a node that has the GPU and the custom resource."""
    seen = {}
    gpu_id, cpu_id = "ab" * 28, "cd" * 28  # node ids as Ray writes them
    gpu_node = {"NodeID": gpu_id, "Alive": True, "Resources": {"CPU": 8.0, "GPU": 1.0, "renderer": 1.0}}
    cpu_node = {"NodeID": cpu_id, "Alive": True, "Resources": {"CPU": 16.0}}
    monkeypatch.setattr(actor.ray, "nodes", lambda: [cpu_node, gpu_node])
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
    assert seen["scheduling_strategy"].node_id == gpu_id and not seen["scheduling_strategy"].soft
    actor.get_or_create(config, None, Recorder)
    assert seen["num_gpus"] == 0.0 and seen["resources"] == {}
