"""Starting this machine's Ray node (``ray start --address ...``), started again when it stalls reaching the head.

A node whose ``ray start`` runs in its head's first second or two can stall inside Ray's own GCS client: it says
"Failed to connect to GCS at address ... within 5 seconds", then nothing for up to a minute, and then either joins
or crashes ("Failed to get system config within the timeout setting"), while the nodes started a second later join
at once and the same command run again joins in about 2 s. On this machine (2026-11-29) the compose stack met it in
two runs of ``docker/verify-stack.sh`` (a worker joined 36 and 52 s late, and the first photo batch waited for it)
and in 2 of 14 bare ``up``s (a worker 76 s late, then the crash; another ~8 s late); each time in the node that
found the head's port still closed and its GCS answering half a second later (:func:`app.netwait.wait_for_gcs` does
not tell that window apart: the health check passes in it). The cause there is the network's DNS: a probe resolving
``ray-head`` every quarter second during ``up`` saw single lookups block 40 s and fail while the containers started
(podman 4.3's aardvark-dns reopens its sockets on every container start and drops queries; this machine's second
nameserver never answers), and Ray's client resolves the name itself (docs/deploy.md).

So the start is watched: when it has printed that stall and has not said "Ray runtime started" within
:data:`JOIN_TRY_S`, its process group is stopped and it is run again (at most :data:`JOIN_TRIES` times). Stopping it
then is safe: a node's GCS client comes before any process of its own (raylet, object store) is started.
"""
from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
from typing import Sequence

log = logging.getLogger("sweepcast.raystart")

STALL_MARK = "Failed to connect to GCS"
"""What Ray's GCS client prints when its first connection did not come up within 5 s."""
STARTED_MARK = "Ray runtime started"
"""What ``ray start`` prints once the node runs."""
JOIN_TRY_S = 15.0
"""How long a start that has printed :data:`STALL_MARK` may take before it is started again (a healthy start takes
2-8 s on a loaded 2-core machine; the stall's mark comes ~7 s after the start)."""
JOIN_TRIES = 5


class _Watched:
    """One ``ray start`` run with its output copied to ours, line by line, noting the two marks."""

    def __init__(self, argv: Sequence[str]) -> None:
        # its own process group: a stalled start is stopped whole; our signals are passed on by hand
        self.proc = subprocess.Popen(list(argv), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, start_new_session=True)
        self.started = threading.Event()
        self.stalled = threading.Event()
        self._copier = threading.Thread(target=self._copy, name="ray-start-output", daemon=True)
        self._copier.start()

    def _copy(self) -> None:
        assert self.proc.stdout is not None
        for raw in iter(self.proc.stdout.readline, b""):
            line = raw.decode("utf-8", "replace")
            sys.stdout.write(line)
            sys.stdout.flush()
            if STARTED_MARK in line:
                self.started.set()
            elif STALL_MARK in line:
                self.stalled.set()

    def stop(self) -> None:
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait()
        self._copier.join(5)

    def wait(self) -> int:
        code = self.proc.wait()
        self._copier.join(5)
        return code


def start_node(argv: Sequence[str], try_s: float = JOIN_TRY_S, tries: int = JOIN_TRIES) -> int:
    """Run ``argv`` (a ``ray start --address ...`` command, with or without ``--block``) to its end, started again
    when it stalls reaching the GCS (module docstring); SIGTERM and SIGINT are passed on to it (on the main thread:
    caught from before the first start, so none is lost in between). Its exit code (1 when every try stalled)."""
    runs: list[_Watched] = []
    received: list[int] = []

    def pass_on(sig: int, _frame: object) -> None:
        received.append(sig)
        if runs and runs[-1].proc.poll() is None:
            runs[-1].proc.send_signal(sig)

    previous = ({sig: signal.signal(sig, pass_on) for sig in (signal.SIGTERM, signal.SIGINT)}
                if threading.current_thread() is threading.main_thread() else {})
    try:
        for attempt in range(1, tries + 1):
            if received:  # told to stop while a stalled try was being stopped
                return 128 + received[-1]
            run = _Watched(argv)
            runs.append(run)
            if received:  # told to stop while it was being started
                run.proc.send_signal(received[-1])
            begun = time.monotonic()
            while run.proc.poll() is None and not run.started.is_set():
                if run.stalled.is_set() and time.monotonic() - begun > try_s:
                    break
                time.sleep(0.1)
            else:
                return run.wait()
            run.stop()
            log.warning("ray start could not reach the head's GCS in %.0f s (try %d of %d): starting it again",
                        try_s, attempt, tries)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    log.error("ray start stalled reaching the head's GCS %d times: giving up", tries)
    return 1
