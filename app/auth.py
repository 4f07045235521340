"""Bearer-key authentication for every ``/v1`` route and socket (when keys are configured).

HTTP requests are checked by :class:`ApiKeyMiddleware` from the headers alone, before anything
reads the body (FastAPI parses a form or JSON body before it runs a route's dependencies, so a
dependency alone would take in a 200 MB upload and then answer 401). :func:`require_key` stays
on the routers for routes mounted without the middleware; sockets check with
:func:`websocket_key_ok`.
"""
from __future__ import annotations

import hmac

from fastapi import Request, WebSocket
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Receive, Scope, Send

from app.errors import ApiError
from app.limits import send_error

PROTECTED_PREFIX = "/v1"
_UNAUTHORIZED = "missing or wrong API key: send 'Authorization: Bearer <key>'"


def _key_ok(presented: str | None, keys: list[str]) -> bool:
    if presented is None:
        return False
    return any(hmac.compare_digest(presented.encode(), k.encode()) for k in keys)


def _bearer(header: str | None) -> str | None:
    if header and header.lower().startswith("bearer "):
        return header[7:].strip()
    return None


def require_key(request: Request) -> None:
    """FastAPI dependency: 401 unless the request carries a configured key."""
    keys = request.app.state.settings.api_keys
    if keys and not _key_ok(_bearer(request.headers.get("authorization")), keys):
        raise ApiError(401, _UNAUTHORIZED, "unauthorized", headers={"WWW-Authenticate": "Bearer"})


class ApiKeyMiddleware:
    """401 for an HTTP request under ``/v1`` without a configured key, answered before the body is
    read (add it after the body limit, so it runs first). No keys: every request passes."""

    def __init__(self, app: ASGIApp, keys: list[str]) -> None:
        self.app = app
        self.keys = list(keys)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and self.keys and _protected(scope["path"]):
            if not _key_ok(_bearer(Headers(scope=scope).get("authorization")), self.keys):
                await send_error(send, 401, _UNAUTHORIZED, "unauthorized", [(b"www-authenticate", b"Bearer")])
                return
        await self.app(scope, receive, send)


def _protected(path: str) -> bool:
    return path == PROTECTED_PREFIX or path.startswith(PROTECTED_PREFIX + "/")


def websocket_key_ok(websocket: WebSocket) -> bool:
    """A socket's key: the Authorization header, or ``?access_token=`` for browsers (which cannot set headers)."""
    keys = websocket.app.state.settings.api_keys
    if not keys:
        return True
    presented = _bearer(websocket.headers.get("authorization")) or websocket.query_params.get("access_token")
    return _key_ok(presented, keys)
