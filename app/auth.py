"""Who a request acts for: bearer keys on every ``/v1`` route and socket.

HTTP requests are checked by :class:`ApiKeyMiddleware` from the headers alone, before anything reads the body
(FastAPI parses a form or JSON body before it runs a route's dependencies, so a dependency alone would take in a
200 MB upload and then answer 401); it puts the request's :class:`~app.keys.Principal` in ``request.state`` for
the routes (:func:`principal`), counts uploads against the key's rate (:mod:`app.quotas`) and names the key in
the access log (:mod:`app.logredact`). Sockets resolve theirs with :func:`socket_principal`.
"""
from __future__ import annotations

import asyncio

from fastapi import Request, WebSocket
from starlette.datastructures import Headers
from starlette.exceptions import WebSocketException
from starlette.types import ASGIApp, Receive, Scope, Send

from app.errors import DATABASE_RETRY_AFTER_S, ApiError
from app.jobstore import DATABASE_DOWN, database_unavailable
from app.keys import SERVICE_ADMIN, KeyStore, Principal, env_key_matches
from app.limits import send_error
from app.logredact import request_key_name

PROTECTED_PREFIX = "/v1"
_UNAUTHORIZED = "missing, wrong, revoked or expired API key: send 'Authorization: Bearer <key>'"


class Authenticator:
    """Turns a presented secret into a principal: the service's own keys (admin), else a managed key (one
    indexed lookup per request, so a revocation holds at once on every replica). Without keys of either kind,
    every caller is the admin principal."""

    def __init__(self, env_keys: list[str], keys: KeyStore | None) -> None:
        self.env_keys = list(env_keys)
        self.keys = keys
        self._managed_seen = False  # keys are revoked, never deleted: once one exists, auth stays on

    @property
    def known_enabled(self) -> bool:
        """Whether requests need a key, as of the last request this replica authenticated (no database read):
        for answers that depend on it, e.g. whether a response may be cached by shared caches."""
        return bool(self.env_keys) or self._managed_seen

    def enabled(self) -> bool:
        """Blocking (may read the database)."""
        if self.env_keys or self._managed_seen:
            return True
        self._managed_seen = self.keys is not None and self.keys.any()
        return self._managed_seen

    def service_key(self, presented: str | None) -> bool:
        """Whether ``presented`` is one of the service's own keys (no database read)."""
        return presented is not None and env_key_matches(presented, self.env_keys)

    def resolve(self, presented: str | None) -> Principal | None:
        """The principal of ``presented`` (None: refuse the request). Blocking (may read the database)."""
        return SERVICE_ADMIN if self.service_key(presented) else self.resolve_managed(presented)

    def resolve_managed(self, presented: str | None) -> Principal | None:
        """:meth:`resolve` for anything but the service's own keys. Blocking (reads the database)."""
        if not self.enabled():
            return SERVICE_ADMIN
        if presented is None or self.keys is None:
            return None
        return self.keys.lookup(presented)


def _bearer(header: str | None) -> str | None:
    if header and header.lower().startswith("bearer "):
        return header[7:].strip()
    return None


def _authenticator(app: ASGIApp) -> Authenticator:
    services = getattr(app.state, "services", None)
    if services is not None:
        return services.auth
    return Authenticator(app.state.settings.api_keys, None)  # an app served without its lifespan (tests)


async def resolve(app: ASGIApp, presented: str | None) -> Principal | None:
    """:meth:`Authenticator.resolve` off the event loop when it needs the database (a managed key, or a service
    that may have none yet); the service's own keys are matched here at once."""
    auth = _authenticator(app)
    if auth.service_key(presented):
        return SERVICE_ADMIN
    if auth.keys is None:  # no managed keys (an app without its lifespan): the service's own keys only
        return None if auth.env_keys else SERVICE_ADMIN
    return await asyncio.to_thread(auth.resolve_managed, presented)


def principal(request: Request) -> Principal:
    """FastAPI dependency: the request's principal (401 when its key is missing or wrong)."""
    found = getattr(request.state, "principal", None)
    if found is None:
        raise ApiError(401, _UNAUTHORIZED, "unauthorized", headers={"WWW-Authenticate": "Bearer"})
    return found


def require_key(request: Request) -> None:
    """Router dependency: 401 unless the request carries a key the middleware accepted."""
    principal(request)


def require_admin(request: Request) -> Principal:
    """FastAPI dependency: the principal, when it is an admin (403 otherwise)."""
    who = principal(request)
    if not who.is_admin:
        raise ApiError(403, "this route needs an admin key", "admin_only")
    return who


class ApiKeyMiddleware:
    """401 for an HTTP request under ``/v1`` without an accepted key, answered before the body is read (add it
    after the body limit, so it runs first); 429 for an upload past its key's rate. Every accepted request
    carries its principal in ``scope["state"]["principal"]``."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and _protected(scope["path"]):
            headers = Headers(scope=scope)
            try:
                who = await resolve(scope["app"], _bearer(headers.get("authorization")))
            except Exception as exc:
                if not database_unavailable(exc):
                    raise
                await send_error(send, 503, DATABASE_DOWN, "database_unavailable",
                                 [(b"retry-after", str(DATABASE_RETRY_AFTER_S).encode())])
                return
            if who is None:
                await send_error(send, 401, _UNAUTHORIZED, "unauthorized", [(b"www-authenticate", b"Bearer")])
                return
            scope.setdefault("state", {})["principal"] = who
            request_key_name.set(who.label)
            services = getattr(scope["app"].state, "services", None)
            if services is not None and _is_upload(scope, headers):
                refused = services.quotas.take_upload(who)
                if refused is not None:
                    await send_error(send, refused.status_code, refused.detail, refused.code,
                                     [(k.lower().encode(), v.encode()) for k, v in (refused.headers or {}).items()])
                    return
        await self.app(scope, receive, send)


def _protected(path: str) -> bool:
    return path == PROTECTED_PREFIX or path.startswith(PROTECTED_PREFIX + "/")


def _is_upload(scope: Scope, headers: Headers) -> bool:
    """A request that sends files: a POST with a multipart form."""
    return scope["method"] == "POST" and headers.get("content-type", "").startswith("multipart/form-data")


async def socket_principal(websocket: WebSocket) -> Principal | None:
    """A socket's principal, from the Authorization header or ``?access_token=`` (browsers cannot set headers)."""
    presented = _bearer(websocket.headers.get("authorization")) or websocket.query_params.get("access_token")
    try:
        who = await resolve(websocket.app, presented)
    except Exception as exc:
        if not database_unavailable(exc):
            raise
        raise WebSocketException(1013, "the job database cannot be reached just now: reconnect in a few seconds"
                                 ) from None  # 1013: try again later
    if who is not None:
        request_key_name.set(who.label)
    return who
