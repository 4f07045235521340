"""The HTTP/1.1 connection handling of the API: uvicorn's httptools protocol with a deadline on request headers.

uvicorn times out an idle keep-alive connection only after a response; a client that opens a connection and
never finishes a request's headers (a slowloris, or a broken proxy) holds it, and a socket of the server, for
ever. Each request's headers must now arrive whole within ``header_timeout_seconds`` of the connection's opening
(the first request) or of the request's first byte (the following ones on a keep-alive connection), else the
client gets a 408 with the service's JSON error body and the connection is closed, with a log line. Request
bodies have their own pace (``app.limits.BodyPace``), once the route is known.

uvicorn's own answer to an unparsable request is a text/plain 400; here it is the JSON error body too.
"""
from __future__ import annotations

import asyncio
import json
import logging

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

log = logging.getLogger("sweepcast.limits")


def error_response(status: int, reason: str, error: str, detail: str) -> bytes:
    """A whole HTTP/1.1 response with the service's error body, closing the connection."""
    body = json.dumps({"error": error, "detail": detail}).encode()
    return (f"HTTP/1.1 {status} {reason}\r\ncontent-type: application/json\r\ncontent-length: {len(body)}\r\n"
            "connection: close\r\n\r\n").encode("ascii") + body


def http_protocol(header_timeout_seconds: float) -> type[HttpToolsProtocol]:
    """The protocol class for ``uvicorn.Config(http=...)``: headers due within ``header_timeout_seconds``."""

    class DeadlineHttpProtocol(HttpToolsProtocol):
        header_timer: asyncio.TimerHandle | None = None

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            self._arm()

        def on_message_begin(self) -> None:
            super().on_message_begin()
            if self.header_timer is None:  # a following request on a keep-alive connection
                self._arm()

        def on_headers_complete(self) -> None:
            self._disarm()
            super().on_headers_complete()

        def connection_lost(self, exc: Exception | None) -> None:
            self._disarm()
            super().connection_lost(exc)

        def send_400_response(self, msg: str) -> None:
            self.transport.write(error_response(400, "Bad Request", "bad_http_request", msg))
            self.transport.close()

        def _arm(self) -> None:
            self.header_timer = self.loop.call_later(header_timeout_seconds, self._headers_overdue)

        def _disarm(self) -> None:
            if self.header_timer is not None:
                self.header_timer.cancel()
                self.header_timer = None

        def _headers_overdue(self) -> None:
            self.header_timer = None
            if self.transport.is_closing():
                return
            client = "%s:%d" % self.client if self.client else "a client"
            log.warning("closed the connection of %s: no whole request headers within %g s", client,
                        header_timeout_seconds)
            self.transport.write(error_response(
                408, "Request Timeout", "request_header_timeout",
                f"the request's headers did not arrive within {header_timeout_seconds:g} s"))
            self.transport.close()

    return DeadlineHttpProtocol
