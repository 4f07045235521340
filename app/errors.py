"""Error responses: every error a user can cause is a 4xx with a JSON body saying what was wrong.

Body: ``{"error": "<short code>", "detail": "<what was wrong, for a person>"}``; validation
errors add ``"fields"`` with pydantic's per-field messages.
"""
from __future__ import annotations

from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from boto3.exceptions import Boto3Error
from botocore.exceptions import BotoCoreError, ClientError
from sqlalchemy import exc as sa_exc
from starlette.routing import Match, Mount

from app.jobstore import DATABASE_DOWN, database_unavailable
from workers.common.errors import InputError
from workers.common.validation import describe_errors
from workers.storage import StoreUnavailable, storage_full, storage_unavailable

_METHODS = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS", "TRACE")


class ApiError(StarletteHTTPException):
    """An HTTP error with a machine-readable code and a human message."""

    def __init__(self, status: int, detail: str, code: str | None = None, headers: dict[str, str] | None = None):
        super().__init__(status_code=status, detail=detail, headers=headers)
        self.code = code or _default_code(status)


def _default_code(status: int) -> str:
    try:
        return HTTPStatus(status).phrase.lower().replace(" ", "_").replace("-", "_")
    except ValueError:
        return "error"


def error_body(status: int, detail: Any, code: str | None = None, **extra: Any) -> dict[str, Any]:
    return {"error": code or _default_code(status), "detail": detail, **extra}


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        code = getattr(exc, "code", None)
        headers = exc.headers
        if exc.status_code == 405 and headers and "Allow" in headers:  # a route's 405 (not a mount's)
            headers = {**headers, "Allow": ", ".join(allowed_methods(request)) or headers["Allow"]}
        return JSONResponse(error_body(exc.status_code, exc.detail, code), exc.status_code, headers=headers)

    @app.exception_handler(InputError)
    async def _input_error(_request: Request, exc: InputError) -> JSONResponse:
        """Every engine's user-facing error: its own status and code (the one mapping; routes only wrap one
        where they add to the message, e.g. the file it came from)."""
        return JSONResponse(error_body(exc.status, str(exc), exc.code), exc.status)

    @app.exception_handler(OSError)
    async def _storage_full(_request: Request, exc: OSError) -> JSONResponse:
        if not storage_full(exc):
            raise exc  # any other OSError is a server error, answered as before
        return JSONResponse(error_body(507, "the service's storage is full: nothing was stored; retry once space is "
                                            "freed", "storage_full"), 507)

    @app.exception_handler(sa_exc.SQLAlchemyError)
    async def _database_down(_request: Request, exc: sa_exc.SQLAlchemyError) -> JSONResponse:
        if not database_unavailable(exc):
            raise exc  # a query's own error is a server error, answered as before
        return database_down_response()

    async def _storage_down(_request: Request, exc: Exception) -> JSONResponse:
        if not storage_unavailable(exc):
            raise exc  # the object store refused a request of ours: a server error, answered as before
        return JSONResponse(error_body(503, STORAGE_DOWN, "storage_unavailable"), 503,
                            headers={"Retry-After": str(STORAGE_RETRY_AFTER_S)})

    for boto_error in (BotoCoreError, ClientError, Boto3Error, StoreUnavailable):
        app.add_exception_handler(boto_error, _storage_down)

    @app.exception_handler(RequestValidationError)
    async def _validation_error(_request: Request, exc: RequestValidationError) -> JSONResponse:
        fields = [
            {"loc": [str(p) for p in e.get("loc", ())], "msg": e.get("msg", ""), "type": e.get("type", "")}
            for e in exc.errors()
        ]
        summary = describe_errors(fields, "request", skip_loc=1)
        return JSONResponse(error_body(422, f"invalid request: {summary}", "invalid_request", fields=fields), 422)


DATABASE_RETRY_AFTER_S = 5
STORAGE_RETRY_AFTER_S = 10
STORAGE_DOWN = ("the object store cannot be reached or is overloaded just now (after retries): nothing was stored or "
                "changed; retry in a little while")


def database_down_response() -> JSONResponse:
    """503 while the job database cannot be reached (nothing was changed; the client may retry)."""
    return JSONResponse(error_body(503, DATABASE_DOWN, "database_unavailable"), 503,
                        headers={"Retry-After": str(DATABASE_RETRY_AFTER_S)})


def allowed_methods(request: Request) -> list[str]:
    """Every method some route serves at this path. Starlette's 405 names only the first route that
    matched the path, so ``GET /v1/jobs/{id}`` and ``DELETE /v1/jobs/{id}`` (two routes) said ``Allow: GET``."""
    routes = [r for r in request.app.router.routes if not isinstance(r, Mount)]  # a mount matches any method
    scope = {"type": "http", "path": request.scope["path"], "root_path": request.scope.get("app_root_path", ""),
             "headers": [], "query_string": b""}
    return [m for m in _METHODS if any(r.matches({**scope, "method": m})[0] == Match.FULL for r in routes)]
