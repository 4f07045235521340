"""A way to cut off a WebSocket whose peer reads nothing.

ASGI can only close a socket by sending a close frame, and a server sends that only once the connection's send
buffer has room: to a peer that stopped reading (a frozen tab, a hostile client) it never goes out, and the
connection, with its buffered frames, stays open for good. :class:`SocketAbortApp` (the service's app) puts the
connection's ``abort`` into each WebSocket scope under :data:`ABORT_KEY`, taken from the server's ``send`` as the
server hands it over: under uvicorn that is its protocol's bound method, whose ``transport`` is the connection. Under a server where it is not (the test client), the key is absent and a stalled socket is only
closed (:func:`abort`).
"""
from __future__ import annotations

from typing import Any, Callable

from fastapi import FastAPI
from starlette.types import Receive, Scope, Send

ABORT_KEY = "sweepcast.abort"


class SocketAbortApp(FastAPI):
    """The service's FastAPI app, which notes each WebSocket connection's ``abort`` in its scope before any
    middleware (FastAPI's own among them) wraps the server's ``send``."""

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "websocket":
            transport = getattr(getattr(send, "__self__", None), "transport", None)
            cut = getattr(transport, "abort", None)  # asyncio's or uvloop's transport (not an asyncio subclass)
            if callable(cut):
                scope[ABORT_KEY] = cut
        await super().__call__(scope, receive, send)


def abort(scope: dict[str, Any]) -> bool:
    """Drop the scope's connection at once (buffered data is discarded); False when the server gave no way."""
    cut: Callable[[], None] | None = scope.get(ABORT_KEY)
    if cut is None:
        return False
    cut()
    return True
