"""Request-body limits per route, enforced while the body is read, before it is buffered.

Each route gets the limit of what it takes (:class:`RouteBodyLimits`): JSON or no body:
``max_json_bytes``; a single-file upload: ``max_upload_bytes``; a batch upload (a route declared with
``openapi_extra=BATCH_BODY``, which the OpenAPI document shows as ``x-body-limit: batch``): ``max_batch_bytes``. The limit is looked up when the route
first asks for the body (the router has matched it by then and put it in the scope): a declared
Content-Length over the limit is refused before a byte is read; a body without one (chunked) is
counted as it streams and refused when it passes the limit. Both give 413 with a JSON body.
"""
from __future__ import annotations

import asyncio
import json
import logging
import time
from dataclasses import dataclass
from typing import Callable, Iterable, Literal

from fastapi import params
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.errors import ApiError, error_body

log = logging.getLogger("sweepcast.limits")
BodyKind = Literal["json", "upload", "batch"]
BATCH_BODY = {"x-body-limit": "batch"}
"""``openapi_extra`` of the true batch uploads (many files, videos, archives): their body may be ``max_batch_bytes``."""


class BodyTooLarge(ApiError):
    def __init__(self, limit: int) -> None:
        super().__init__(413, _too_large(limit), "payload_too_large")


class BodyTooSlow(ApiError):
    def __init__(self, detail: str) -> None:
        super().__init__(408, detail, "upload_too_slow")


@dataclass(frozen=True)
class BodyPace:
    """How slowly a client may send a body: ``idle_seconds`` at most between two chunks, and after ``grace_seconds``
    at least ``min_bytes_per_second`` on average. A stalled or trickling upload is cut off with 408 (it holds no
    worker, but a connection and a spooled file each)."""

    idle_seconds: float = 60.0
    grace_seconds: float = 60.0
    min_bytes_per_second: float = 1024.0

    def too_slow(self, received: int, elapsed: float) -> str | None:
        """Why ``received`` bytes in ``elapsed`` seconds are too slow, or None."""
        if elapsed > self.grace_seconds and received < self.min_bytes_per_second * elapsed:
            return (f"the request body arrived at {received / elapsed:,.0f} bytes/s, under the "
                    f"{self.min_bytes_per_second:,.0f} bytes/s this service needs; send it faster")
        return None


class RouteBodyLimits:
    """The body limit of a request by its route (``scope["route"]``), resolved once per route.

    ``limits``: bytes per kind of body. A route declared with :data:`BATCH_BODY` is a batch upload, a route
    with a ``File`` parameter an upload, any other route takes JSON (or nothing).
    """

    def __init__(self, limits: dict[BodyKind, int]) -> None:
        self.limits = limits
        self._kinds: dict[tuple[str, str], BodyKind] = {}

    def __call__(self, scope: Scope) -> int:
        return self.limits[self.kind(scope)]

    def kind(self, scope: Scope) -> BodyKind:
        """What the matched route of ``scope`` takes; "json" (the smallest) when there is none."""
        route = scope.get("route")
        if not isinstance(route, APIRoute):
            return "json"
        key = (scope["method"], route.path)
        if key not in self._kinds:
            batch = (route.openapi_extra or {}).get("x-body-limit") == "batch"
            self._kinds[key] = "batch" if batch else ("upload" if _takes_files(route) else "json")
        return self._kinds[key]


def _takes_files(route: APIRoute) -> bool:
    """Whether the route's body has a file field (``File(...)``: multipart uploads)."""
    return _has_file(route.dependant)


def _has_file(dependant: Dependant) -> bool:
    return (any(isinstance(f.field_info, params.File) for f in dependant.body_params)
            or any(_has_file(d) for d in dependant.dependencies))


class BodyLimitMiddleware:
    def __init__(self, app: ASGIApp, limit_for: Callable[[Scope], int], pace: BodyPace | None = None) -> None:
        self.app = app
        self.limit_for = limit_for
        self.pace = pace or BodyPace()

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = _content_length(scope)
        limit: int | None = None
        received = 0
        started = False
        began = time.monotonic()

        async def counting_receive() -> Message:
            nonlocal received, limit
            if limit is None:  # the first read: the route is matched and in the scope
                limit = self.limit_for(scope)
                if declared is not None and declared > limit:
                    raise BodyTooLarge(limit)
            try:
                message = await asyncio.wait_for(receive(), self.pace.idle_seconds)
            except asyncio.TimeoutError:
                raise _cut_off(scope, f"no part of the request body arrived for {self.pace.idle_seconds:.0f} s"
                               ) from None
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise BodyTooLarge(limit)
                if message.get("more_body") and (why := self.pace.too_slow(received, time.monotonic() - began)):
                    raise _cut_off(scope, why)
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, counting_receive, tracking_send)
        except (BodyTooLarge, BodyTooSlow) as exc:
            if not started:
                await send_error(send, exc.status_code, str(exc.detail), exc.code)


def _cut_off(scope: Scope, why: str) -> BodyTooSlow:
    """The 408 of a stalled or trickling body, said in the log with its route."""
    log.warning("cut off %s %s: %s", scope["method"], scope["path"], why)
    return BodyTooSlow(why)


def _too_large(limit: int) -> str:
    return f"request body is larger than the limit of {limit} bytes for this route"


def _content_length(scope: Scope) -> int | None:
    for name, value in scope.get("headers", ()):
        if name == b"content-length":
            try:
                return int(value)
            except ValueError:
                return None
    return None


async def send_error(send: Send, status: int, detail: str, code: str,
                     headers: Iterable[tuple[bytes, bytes]] = ()) -> None:
    """Answer with the service's JSON error body from ASGI middleware (the body unread: close after)."""
    body = json.dumps(error_body(status, detail, code)).encode()
    await send({
        "type": "http.response.start",
        "status": status,
        "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                    (b"connection", b"close"), *headers],
    })
    await send({"type": "http.response.body", "body": body})
