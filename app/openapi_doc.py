"""The OpenAPI document: FastAPI's schema corrected to say what the service really answers.

FastAPI documents only the success response and its own 422 body (``HTTPValidationError``, whose
``detail`` is a list), and it describes multipart form fields as Python sees them. The service
answers every error as ``{"error", "detail"}`` (app/errors.py), guards ``/v1`` with bearer keys,
limits bodies, and reads each ``params`` form field as a JSON object. :func:`document_contract`
rewrites the generated schema to say so, in one place, so that routes stay plain: what is a route's own
(its statuses, its media types, its ``params`` model, declared with :func:`app.params_form.params_form`) is read
off the route's own document; this module adds only what every route of a kind shares. The live ``/openapi.json`` and the
committed ``openapi/openapi.json`` are the same document.
``tests/app/test_contract_fuzz.py`` fuzzes the live service against it.
"""
from __future__ import annotations

import copy
import json
from typing import TYPE_CHECKING, Any, Callable


from pydantic import BaseModel

from app.params_form import MODEL_KEY, declared_model

if TYPE_CHECKING:
    from fastapi import FastAPI

ERROR = "Error"
VALIDATION_ERROR = "ValidationErrorResponse"
BEARER = "bearerAuth"
SECURITY_SCHEMES = {BEARER: {
    "type": "http", "scheme": "bearer",
    "description": "an API key: a managed one (`sweepcast keys create`, `POST /v1/keys`) or one of "
                   "SWEEPCAST_API_KEYS (admin); a service without keys accepts requests without one. A user key "
                   "sees only its own resources. Sockets also take `?access_token=<key>`.",
}}
_FASTAPI_422 = "#/components/schemas/HTTPValidationError"

# Statuses every operation of a kind can answer (what causes them is the same everywhere).
AUTH_STATUS = {401: "missing, wrong, revoked or expired API key: send `Authorization: Bearer <key>` (only when the "
                    "service has keys)"}
BACKEND_STATUS = {503: "a backend the service needs cannot be reached just now: the job database "
                       "(`database_unavailable`) or the object store (`storage_unavailable`); nothing was changed: "
                       "retry after `Retry-After` seconds"}
UPLOAD_STATUS = {429: "the key sent its most uploads this minute (its uploads_per_minute quota): retry after "
                      "`Retry-After` seconds"}
NEW_JOB_STATUSES = {
    429: "the key has its most jobs queued or running (active_jobs quota), or sent its most uploads this minute: "
         "retry after `Retry-After` seconds",
    507: "the job's inputs would take the key past its stored_bytes quota, or the service's storage is nearly "
         "full (SWEEPCAST_MIN_FREE_STORAGE_MB); nothing was stored",
}
BODY_STATUSES = {
    400: "the body could not be parsed (malformed multipart or JSON), or an upload is empty or unreadable",
    408: "the request body stalled (SWEEPCAST_UPLOAD_IDLE_SECONDS) or arrived slower than "
         "SWEEPCAST_MIN_UPLOAD_BYTES_PER_SECOND",
    413: "the request body, or one upload in it, is over the service's limit",
}
PATH_STATUS = {404: "nothing exists under the id (or name) in the path, or it belongs to another key"}
VALIDATION_DESCRIPTION = ("invalid request: a parameter, form field or `params` object is wrong; request "
                          "validation errors list each problem in `fields`")


class ContractError(RuntimeError):
    """The document cannot be corrected as it stands (a ``params`` field without its model, two schemas of one
    name)."""


def error_schemas() -> dict[str, Any]:
    field_error = {
        "type": "object",
        "required": ["loc", "msg", "type"],
        "properties": {
            "loc": {"type": "array", "items": {"type": "string"},
                    "description": "where: 'query', 'path', 'body' or 'header', then the field's path"},
            "msg": {"type": "string"},
            "type": {"type": "string", "description": "pydantic's error type, e.g. missing"},
        },
    }
    return {
        ERROR: {
            "title": ERROR,
            "type": "object",
            "required": ["error", "detail"],
            "properties": {
                "error": {"type": "string", "description": "a short code, e.g. job_not_found"},
                "detail": {"type": "string", "description": "what was wrong, for a person"},
            },
        },
        VALIDATION_ERROR: {
            "title": VALIDATION_ERROR,
            "type": "object",
            "required": ["error", "detail"],
            "properties": {
                "error": {"type": "string", "description": "invalid_request for request validation, else a "
                                                          "route's code such as invalid_parameters"},
                "detail": {"type": "string", "description": "what was wrong, for a person"},
                "fields": {"type": "array", "items": field_error,
                           "description": "request validation only: each field that was wrong"},
            },
        },
    }


def _ref(name: str) -> dict[str, str]:
    return {"$ref": f"#/components/schemas/{name}"}


def _error_response(description: str, schema: str = ERROR) -> dict[str, Any]:
    return {"description": description, "content": {"application/json": {"schema": _ref(schema)}}}


def _operations(doc: dict[str, Any]) -> list[tuple[str, str, dict[str, Any]]]:
    methods = ("get", "put", "post", "delete", "patch", "head", "options", "trace")
    return [(m, path, op) for path, item in doc.get("paths", {}).items() for m, op in item.items() if m in methods]


def _add_errors(op: dict[str, Any], statuses: dict[int, str]) -> None:
    """Document ``statuses`` with the error body; keep a description a route gave (it says more)."""
    responses = op.setdefault("responses", {})
    for status, description in statuses.items():
        given = responses.get(str(status), {}).get("description")
        responses[str(status)] = _error_response(given or description)


def _document_errors(doc: dict[str, Any]) -> None:
    for method, path, op in _operations(doc):
        responses = op.setdefault("responses", {})
        statuses: dict[int, str] = {}
        if path.startswith("/v1/"):  # app.auth guards every /v1 route (reading keys from the job database)
            statuses |= AUTH_STATUS | BACKEND_STATUS
            op["security"] = [{BEARER: []}]
        if "requestBody" in op:
            statuses |= BODY_STATUSES  # app.limits guards every body; parsing can fail on any
        if "multipart/form-data" in op.get("requestBody", {}).get("content", {}):
            statuses |= UPLOAD_STATUS  # app.auth counts uploads against the key's rate
        if "202" in responses:  # app.services.create_job checks the key's job and storage quotas
            statuses |= NEW_JOB_STATUSES
        if any(p.get("in") == "path" for p in op.get("parameters", [])):
            statuses |= PATH_STATUS
        # statuses a route declares itself (``responses=``): the error body, with the route's description
        statuses |= {int(s): r.get("description", "") for s, r in responses.items()
                     if s[0] in "45" and "content" not in r}
        _add_errors(op, statuses)
        if "422" in responses or op.get("parameters") or "requestBody" in op:
            responses["422"] = _error_response(VALIDATION_DESCRIPTION, VALIDATION_ERROR)


def _without_null(schema: dict[str, Any]) -> dict[str, Any]:
    """``X | None`` form fields: a multipart part cannot be null, a client leaves it out."""
    options = schema.get("anyOf")
    if not isinstance(options, list):
        return schema
    kept = [o for o in options if o != {"type": "null"}]
    if not kept:
        return schema
    rest = {k: v for k, v in schema.items() if k != "anyOf" and not (k == "default" and v is None)}
    return {**kept[0], **rest} if len(kept) == 1 else {**rest, "anyOf": kept}


def _model_schema(model: type[BaseModel], components: dict[str, Any]) -> dict[str, Any]:
    """``model``'s JSON schema under components (with its $defs), as a reference."""
    schema = model.model_json_schema(ref_template="#/components/schemas/{model}")
    for name, sub in {**schema.pop("$defs", {}), model.__name__: schema}.items():
        if components.setdefault(name, sub) != sub:
            raise ContractError(f"two different schemas are called {name!r}; rename one of the models")
    return _ref(model.__name__)


def _document_forms(doc: dict[str, Any]) -> None:
    components = doc["components"]["schemas"]
    for method, path, op in _operations(doc):
        media = op.get("requestBody", {}).get("content", {}).get("multipart/form-data")
        if media is None:
            continue
        body = components[media["schema"]["$ref"].rsplit("/", 1)[-1]]
        required = set(body.get("required", []))
        props = body.get("properties", {})
        for name, prop in list(props.items()):
            prop = _without_null(prop)
            if prop.get("type") == "array" and name in required:
                prop["minItems"] = 1  # a list with no part is a missing field
            props[name] = prop
        if "params" in props:
            model = declared_model(props["params"].get(MODEL_KEY, ""))
            if model is None:
                raise ContractError(f"{method.upper()} {path} has a 'params' form field without its model: declare "
                                    f"it with app.params_form.params_form")
            keep = {k: props["params"][k] for k in ("description", "title") if k in props["params"]}
            props["params"] = {**_model_schema(model, components), **keep}
            # JSON text in a form field; a client (and the fuzzer) sends the object as application/json.
            media.setdefault("encoding", {})["params"] = {"contentType": "application/json"}


def _drop_unused(doc: dict[str, Any], names: tuple[str, ...]) -> None:
    """Remove the schemas ``names`` (in order) that nothing else refers to any more."""
    schemas = doc["components"]["schemas"]
    for name in names:
        others = {**doc, "components": {**doc["components"], "schemas": {k: v for k, v in schemas.items() if k != name}}}
        if f'"#/components/schemas/{name}"' not in json.dumps(others):
            schemas.pop(name, None)


def document_contract(doc: dict[str, Any]) -> dict[str, Any]:
    """A copy of FastAPI's ``doc`` that describes the service's real errors and form fields."""
    doc = copy.deepcopy(doc)
    doc.setdefault("components", {}).setdefault("schemas", {}).update(error_schemas())
    doc["components"]["securitySchemes"] = SECURITY_SCHEMES
    _document_errors(doc)
    _document_forms(doc)
    if _FASTAPI_422 in json.dumps(doc["paths"]):
        raise ContractError("a response still uses FastAPI's HTTPValidationError")
    _drop_unused(doc, ("HTTPValidationError", "ValidationError"))
    return doc


def install_contract(app: FastAPI) -> None:
    """Serve the corrected document at ``/openapi.json`` (and so in ``/docs``)."""
    generate: Callable[[], dict[str, Any]] = app.openapi

    def openapi() -> dict[str, Any]:
        if not getattr(app.state, "contract_openapi", None):
            app.state.contract_openapi = document_contract(generate())
        return app.state.contract_openapi

    app.openapi = openapi  # type: ignore[method-assign]
