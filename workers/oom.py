"""How many processes the kernel's OOM killer has ended in this process's memory cgroup (its container's, on a
containerised node): a job whose worker died while that count went up was killed for want of memory, which Ray
cannot tell from any other crash (its own memory monitor says so only when it is the one that stops a task)."""
from __future__ import annotations

from pathlib import Path

PROC_CGROUP = Path("/proc/self/cgroup")
CGROUP_ROOT = Path("/sys/fs/cgroup")


def oom_kills(proc_cgroup: Path = PROC_CGROUP, root: Path = CGROUP_ROOT) -> int | None:
    """The ``oom_kill`` count of this process's memory cgroup: cgroup v1's ``memory.oom_control`` under
    ``root/memory/<path>`` (or ``root/memory`` in a container that lists a host path), else cgroup v2's
    ``memory.events`` under ``root/<path>`` (``<path>`` as ``proc_cgroup`` lists it; a container with its own cgroup
    namespace sees its group as ``/``). None where neither file says (not Linux, no memory controller, a kernel
    before 4.13)."""
    try:
        lines = proc_cgroup.read_text().splitlines()
    except OSError:
        return None
    paths = {}
    for line in lines:
        _, controllers, path = line.split(":", 2)
        for name in controllers.split(",") if controllers else ["unified"]:
            paths[name] = path.lstrip("/")
    # A container on cgroup v1 without a cgroup namespace lists its host path, yet has its own group mounted at the
    # controller's root: then the path is missing and the root is the container's.
    candidates = []
    if "memory" in paths:
        candidates += [root / "memory" / paths["memory"] / "memory.oom_control", root / "memory" / "memory.oom_control"]
    if "unified" in paths:
        candidates += [root / paths["unified"] / "memory.events", root / "unified" / paths["unified"] / "memory.events"]
    for path in candidates:
        try:
            fields = dict(line.split() for line in path.read_text().splitlines() if len(line.split()) == 2)
        except (OSError, ValueError):
            continue
        if "oom_kill" in fields:
            return int(fields["oom_kill"])
    return None
