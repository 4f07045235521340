"""The kernel's OOM kills in this process's memory cgroup, read as cgroup v1 and v2 write them."""
from pathlib import Path

import ray

from workers.oom import oom_kills


def _cgroup(tmp_path: Path, lines: str) -> Path:
    proc = tmp_path / "proc-self-cgroup"
    proc.write_text(lines)
    return proc


def test_cgroup_v1_memory_oom_control_of_the_processs_own_group(tmp_path):
    root = tmp_path / "sys"
    (root / "memory" / "libpod_parent" / "c1").mkdir(parents=True)
    (root / "memory" / "libpod_parent" / "c1" / "memory.oom_control").write_text(
        "oom_kill_disable 0\nunder_oom 0\noom_kill 3\n")
    proc = _cgroup(tmp_path, "5:devices:/\n4:memory:/libpod_parent/c1\n1:cpu,cpuacct:/\n0::/\n")
    assert oom_kills(proc, root) == 3


def test_a_container_on_cgroup_v1_lists_its_host_path_and_has_its_group_at_the_root(tmp_path):
    """podman on cgroup v1 (no cgroup namespace): /proc/self/cgroup names /libpod_parent/libpod-<id>, while the
    container's /sys/fs/cgroup/memory is that group itself (the compose chaos run's workers: a count of 3)."""
    (tmp_path / "memory").mkdir()
    (tmp_path / "memory" / "memory.oom_control").write_text("oom_kill_disable 0\nunder_oom 0\noom_kill 3\n")
    assert oom_kills(_cgroup(tmp_path, "4:memory:/libpod_parent/libpod-2eb1117d\n"), tmp_path) == 3


def test_cgroup_v2_memory_events(tmp_path):
    root = tmp_path / "sys"
    (root / "system.slice" / "x.scope").mkdir(parents=True)
    (root / "system.slice" / "x.scope" / "memory.events").write_text("low 0\nhigh 0\nmax 7\noom 2\noom_kill 2\n")
    assert oom_kills(_cgroup(tmp_path, "0::/system.slice/x.scope\n"), root) == 2


def test_no_memory_controller_or_no_count_is_none(tmp_path):
    assert oom_kills(tmp_path / "missing", tmp_path) is None
    (tmp_path / "memory").mkdir()
    (tmp_path / "memory" / "memory.oom_control").write_text("oom_kill_disable 0\nunder_oom 0\n")  # before Linux 4.13
    assert oom_kills(_cgroup(tmp_path, "4:memory:/\n"), tmp_path) is None


def test_a_node_answers_its_count(ray_local):
    from workers.ray_tasks import node_oom_kills

    assert ray.get(node_oom_kills.remote(), timeout=60) == oom_kills()
