"""Waiting for a server's port before starting what needs it (a Ray node joining its head, the head its Redis).

``ray start --address`` gives a head that is not answering yet one try and then waits about 40 s before the next
(5 s to connect, 5 s for its pubsub, 30 s for the cluster id): in the compose stack, whose containers start at once,
a worker or API node that came up a second before its head then joined 40-60 s late, and the first job waited for
it (docker/verify-stack.sh, 2026-11-29: the first photo batch waited 49 s to start; in 5 bare `up`s the nodes joined
after 12, 21, 43-62, 12 s and, with the head's GCS failing once on a Redis that was still starting, not in 75 s).
A TCP connect every half second ends the wait within half a second of the port opening. A Redis is waited for
until it has loaded its data: the compose stack's head, started as soon as Redis took connections, crashed its GCS
on a Redis still replaying its append-only file after `down`/`up`, and was back only 85 s later.
A Ray head is then waited for until its GCS serves, not only until its port opens: the GCS's port accepts
connections a second or more before it answers, and a ``ray start`` that connected then waited its 30 s for the
cluster id (verify-stack, 2026-11-29 08:11: a worker saw the port open at 08:10:58.7, the head said "Ray runtime
started" at 08:11:00.2, and the worker joined at 08:11:35; the first photo batch waited 28 s).
"""
from __future__ import annotations

import logging
import socket
import subprocess
import time

log = logging.getLogger("sweepcast.netwait")


def split_address(address: str) -> tuple[str, int]:
    """``host:port`` (an optional ``scheme://`` prefix is dropped) as (host, port); ValueError when it is not one."""
    host, sep, port = address.split("://", 1)[-1].rstrip("/").rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ValueError(f"{address!r} is not host:port")
    return host.strip("[]"), int(port)


def wait_for_port(address: str, timeout_s: float, what: str, redis: bool = False,
                  reached: list[str] | None = None) -> float | None:
    """Until a TCP connection to ``address`` (``host:port``) succeeds, trying every half second (a name that does
    not resolve yet counts as not answering); with ``redis``, until the server also answers a PING other than with
    ``-LOADING`` (a Redis replaying its append-only file accepts connections and refuses every command: the Ray
    head's GCS then fails). The seconds waited, or None after ``timeout_s``; the ``ip:port`` the connection reached
    is appended to ``reached``. Logs once when it has to wait, and again when the server answers."""
    host, port = split_address(address)
    started = time.monotonic()
    said = False
    while True:
        try:
            with socket.create_connection((host, port), timeout=2.0) as conn:
                if redis and _redis_loading(conn):
                    raise ConnectionRefusedError("Redis is loading its data")
                if reached is not None:
                    ip = conn.getpeername()[0]
                    reached.append(f"[{ip}]:{port}" if ":" in ip else f"{ip}:{port}")
                waited = time.monotonic() - started
                if said:
                    log.info("%s at %s answers after %.1f s", what, address, waited)
                return waited
        except OSError as exc:
            if not said:
                log.info("waiting for %s at %s (%s)", what, address, exc)
                said = True
        if time.monotonic() - started > timeout_s:
            log.warning("%s at %s did not answer in %.0f s", what, address, timeout_s)
            return None
        time.sleep(0.5)


GCS_CHECK_S = 5.0
"""How long one ``ray health-check`` may take: it answers in ~0.6 s from a serving GCS and hangs on one that is not."""


def wait_for_gcs(address: str, timeout_s: float, ray_bin: str) -> float | None:
    """Until the Ray GCS at ``address`` (``host:port``) answers: :func:`wait_for_port`, then ``ray health-check``
    (``ray_bin``, each try cut at :data:`GCS_CHECK_S`) every half second until one exits 0. The seconds waited, or
    None after ``timeout_s``. Logs when it has to wait, and when the GCS answers."""
    started = time.monotonic()
    if wait_for_port(address, timeout_s, "the Ray head") is None:
        return None
    said = False
    while True:
        try:
            check = subprocess.run([ray_bin, "health-check", "--address", address, "--skip-version-check"],
                                   stdin=subprocess.DEVNULL, capture_output=True, timeout=GCS_CHECK_S)
            if check.returncode == 0:
                waited = time.monotonic() - started
                if said:
                    log.info("the Ray head's GCS at %s answers after %.1f s", address, waited)
                return waited
            reason = f"ray health-check exited with code {check.returncode}"
        except subprocess.TimeoutExpired:
            reason = f"no answer in {GCS_CHECK_S:.0f} s"
        if not said:
            log.info("the Ray head's port at %s is open; waiting for its GCS to serve (%s)", address, reason)
            said = True
        if time.monotonic() - started > timeout_s:
            log.warning("the Ray head's GCS at %s did not answer in %.0f s", address, timeout_s)
            return None
        time.sleep(0.5)


def _redis_loading(conn: socket.socket) -> bool:
    """Whether the Redis server on ``conn`` answers PING with ``-LOADING`` (or not at all)."""
    conn.sendall(b"PING\r\n")
    reply = conn.recv(64)
    return not reply or reply.startswith(b"-LOADING")
