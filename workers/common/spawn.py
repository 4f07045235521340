"""Command lines for child processes that need something set between fork and exec, set by a program instead.

Python's ``preexec_fn`` runs interpreter code in the forked child of a process that has other threads (Ray's, a
decoder's), and the child can deadlock there on a lock one of them held at the fork: CI stop 71 hung for 90 minutes
on an exiftool child stuck in a PyAV scaler's free, which the child's garbage collection ran before its exec. So
nothing here runs Python in a child: util-linux's ``setpriv`` and coreutils' ``nice`` set the parent-death signal and
the niceness, then exec the command, and ``subprocess`` forks with its safe path (vfork, no Python in the child).
"""
from __future__ import annotations

import shutil
import sys
from collections.abc import Sequence


def dying_with_parent(argv: Sequence[str], signal_name: str = "TERM") -> list[str]:
    """``argv`` run so that the kernel sends it SIG``signal_name`` when the thread that starts it ends (Linux's
    parent-death signal, set by ``setpriv --pdeathsig``): a kept-open child of a killed process stops with it.
    The signal is set just before the command's exec, so a thread that ends before the command has started
    (milliseconds) goes unwatched: start children from a thread that then uses them, as every caller here does.
    ``argv`` unchanged where ``setpriv`` is not installed or the system is not Linux (no such signal there)."""
    setpriv = shutil.which("setpriv") if sys.platform.startswith("linux") else None
    if setpriv is None:
        return list(argv)
    return [setpriv, f"--pdeathsig={signal_name}", "--", *argv]


def niced(argv: Sequence[str], increment: int) -> list[str]:
    """``argv`` run ``increment`` niceness steps below this process (coreutils ``nice -n``), from its first
    instruction and for every thread it starts; ``argv`` unchanged where ``nice`` is not installed."""
    nice = shutil.which("nice")
    if nice is None:
        return list(argv)
    return [nice, "-n", str(increment), "--", *argv]
