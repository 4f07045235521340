"""Secrets out of the server's logs, and the acting key's name in: the browser's ``?access_token=`` key (sockets
cannot send an Authorization header) is part of the request line uvicorn logs.

:func:`install_log_redaction` puts :class:`RedactQuerySecrets` on uvicorn's access logger (HTTP
request lines) and error logger (WebSocket handshakes are logged there); each replaces the value
of a secret query parameter with ``***`` in the message and its arguments before any handler
formats them. :class:`NameTheKey` adds the name of the request's key (never its secret), which
the authentication middleware sets in :data:`request_key_name`, to each access line.
"""
from __future__ import annotations

import contextvars
import logging
import re
from typing import Any

SECRET_PARAMS = ("access_token", "api_key", "token")
REDACTED = "***"
UVICORN_LOGGERS = ("uvicorn.access", "uvicorn.error")
request_key_name: contextvars.ContextVar[str | None] = contextvars.ContextVar("request_key_name", default=None)
"""The name (and id) of the key the current request acts with; None before authentication."""
_SECRET_QUERY = re.compile(r"([?&](?:%s)=)[^&#\s\"']*" % "|".join(SECRET_PARAMS), re.IGNORECASE)


def redact(text: str) -> str:
    """``text`` with the value of every secret query parameter replaced by ``***``."""
    return _SECRET_QUERY.sub(r"\g<1>" + REDACTED, text)


class RedactQuerySecrets(logging.Filter):
    """Redacts secret query parameters in a record's message and string arguments; drops nothing."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.msg, str):
            record.msg = redact(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(_redacted(a) for a in record.args)
        elif isinstance(record.args, dict):
            record.args = {k: _redacted(v) for k, v in record.args.items()}
        return True


class NameTheKey(logging.Filter):
    """Adds ``key=<name>`` after the client address of uvicorn's access lines of authenticated requests (its
    formatter reads exactly five arguments, so the address carries it); drops nothing."""

    def filter(self, record: logging.LogRecord) -> bool:
        name = request_key_name.get()
        if name is not None and isinstance(record.args, tuple) and record.args:
            record.args = (f"{record.args[0]} key={name}", *record.args[1:])
        return True


def _redacted(value: Any) -> Any:
    return redact(value) if isinstance(value, str) else value


def install_log_redaction(names: tuple[str, ...] = UVICORN_LOGGERS) -> None:
    """Add the filter to each logger once (uvicorn's logging set-up keeps the filters of a logger)."""
    for name in names:
        logger = logging.getLogger(name)
        if not any(isinstance(f, RedactQuerySecrets) for f in logger.filters):
            logger.addFilter(RedactQuerySecrets())
    access = logging.getLogger("uvicorn.access")
    if not any(isinstance(f, NameTheKey) for f in access.filters):
        access.addFilter(NameTheKey())
