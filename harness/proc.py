"""What Linux's /proc says about a process and its descendants: memory, CPU time, the process tree.

Every reader answers NaN (or an empty list) for a process that is gone instead of raising: the benchmarks sample
processes that may end between two reads."""
from __future__ import annotations

import math
import os
from collections import defaultdict
from pathlib import Path


def status(pid: int) -> dict[str, str]:
    """The fields of /proc/PID/status (``{"VmRSS": "1234 kB", "Threads": "7", ...}``); empty when it is gone."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return {}
    return {name: value.strip() for name, _, value in (line.partition(":") for line in text.splitlines()) if value}


def status_mb(pid: int, field: str, fields: dict[str, str] | None = None) -> float:
    """A kB field of /proc/PID/status (``VmRSS``, ``VmHWM``, ``RssShmem``...) in MB (2**20 bytes); NaN when the
    process is gone or has no such field. ``fields``: a :func:`status` already read."""
    value = (status(pid) if fields is None else fields).get(field)
    return int(value.split()[0]) / 1024 if value else float("nan")


def cpu_seconds(pid: int, reaped: bool = False) -> float:
    """User + system CPU seconds of one process (all its threads); ``reaped``: with those of the children it has
    waited for (gone processes a tree reading would miss); NaN when it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    ticks = fields[11:15] if reaped else fields[11:13]  # utime, stime, then cutime, cstime
    return sum(int(v) for v in ticks) / os.sysconf("SC_CLK_TCK")


def descendants(root: int) -> list[int]:
    """``root`` and every process under it alive now, ``root`` first."""
    children: dict[int, list[int]] = defaultdict(list)
    for entry in os.scandir("/proc"):
        if entry.name.isdigit():
            try:
                stat = Path(f"/proc/{entry.name}/stat").read_text()
                children[int(stat[stat.rindex(")") + 2:].split()[1])].append(int(entry.name))
            except (OSError, ValueError, IndexError):
                continue
    out, todo = [], [root]
    while todo:
        pid = todo.pop()
        out.append(pid)
        todo.extend(children.get(pid, []))
    return out


def tree_cpu_seconds(root: int, reaped: bool = False) -> float:
    """User + system CPU seconds of ``root`` and its descendants alive now (those gone meanwhile count 0, unless
    ``reaped``: then the children each of them has waited for count too)."""
    return sum(s for s in (cpu_seconds(pid, reaped) for pid in descendants(root)) if not math.isnan(s))


def machine_busy_seconds() -> float:
    """CPU seconds all cores of this machine have spent busy (not idle, not waiting for I/O) since boot."""
    values = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return (sum(values) - values[3] - values[4]) / os.sysconf("SC_CLK_TCK")
