"""What a WebSocket's own connection says: how much it still holds for the peer, and a way to cut it off.

ASGI can only close a socket by sending a close frame, and a server sends that only once the connection's send
buffer has room: to a peer that stopped reading (a frozen tab, a hostile client) it never goes out, and the
connection, with its buffered frames, stays open for good. Nor does ASGI say whether the peer took what was sent:
a send returns once the bytes are in the server's buffers, and the kernel's buffers hold a megabyte or more.
:class:`TransportApp` (the service's app) puts each WebSocket connection's transport into its scope under
:data:`TRANSPORT_KEY`, taken from the server's ``send`` as the server hands it over: under uvicorn that is its
protocol's bound method, whose ``transport`` is the connection. Under a server where it is not (the test client)
the key is absent: :func:`queued_bytes` knows nothing and :func:`abort` can only leave the socket to be closed.
"""
from __future__ import annotations

import array
import fcntl
import termios
from typing import Any

from fastapi import FastAPI
from starlette.types import Receive, Scope, Send

TRANSPORT_KEY = "sweepcast.transport"


class TransportApp(FastAPI):
    """The service's FastAPI app, which notes each WebSocket connection's transport in its scope before any
    middleware (FastAPI's own among them) wraps the server's ``send``."""

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "websocket":
            transport = getattr(getattr(send, "__self__", None), "transport", None)
            if callable(getattr(transport, "abort", None)):  # asyncio's or uvloop's (not an asyncio subclass)
                scope[TRANSPORT_KEY] = transport
        await super().__call__(scope, receive, send)


def queued_bytes(scope: dict[str, Any]) -> int | None:
    """Bytes sent to the scope's connection that its peer has not yet acknowledged: the server's write buffer
    and the kernel's send queue (Linux's SIOCOUTQ); None when unknown (no transport, another OS)."""
    transport = scope.get(TRANSPORT_KEY)
    if transport is None or transport.is_closing():
        return None
    sock = transport.get_extra_info("socket")
    try:
        queue = array.array("i", [0])
        fcntl.ioctl(sock.fileno(), termios.TIOCOUTQ, queue)  # TIOCOUTQ is SIOCOUTQ on Linux
    except (AttributeError, OSError, ValueError):
        return None
    return transport.get_write_buffer_size() + queue[0]


def abort(scope: dict[str, Any]) -> bool:
    """Drop the scope's connection at once (what is buffered is discarded); False when the server gave no way."""
    transport = scope.get(TRANSPORT_KEY)
    if transport is None:
        return False
    transport.abort()
    return True
