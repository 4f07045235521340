"""Bearer-key authentication for every ``/v1`` route and socket (when keys are configured)."""
from __future__ import annotations

import hmac

from fastapi import Request, WebSocket

from app.errors import ApiError


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
        raise ApiError(401, "missing or wrong API key: send 'Authorization: Bearer <key>'", "unauthorized",
                       headers={"WWW-Authenticate": "Bearer"})


def websocket_key_ok(websocket: WebSocket) -> bool:
    """A socket's key: the Authorization header, or ``?access_token=`` for browsers (which cannot set headers)."""
    keys = websocket.app.state.settings.api_keys
    if not keys:
        return True
    presented = _bearer(websocket.headers.get("authorization")) or websocket.query_params.get("access_token")
    return _key_ok(presented, keys)
