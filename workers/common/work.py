"""What one synchronous request will cost the process that runs it, estimated before the work starts (the engines
say how; ``app/sync_work.py`` bounds it)."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class WorkEstimate:
    """cpu_seconds: CPU time of the whole request on the reference machine (2-core AMD EPYC; s, all threads
    together); peak_bytes: the most memory it holds at once beyond its uploaded bytes."""

    cpu_seconds: float
    peak_bytes: int

    def __add__(self, other: "WorkEstimate") -> "WorkEstimate":
        return WorkEstimate(self.cpu_seconds + other.cpu_seconds, self.peak_bytes + other.peak_bytes)
