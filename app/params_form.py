"""A route's ``params`` form field: one JSON object that is one pydantic model, declared once on the route.

A multipart route (uploads beside its options) takes its options as the form field ``params``, a JSON object read
strictly into the engine's parameter model. The route names the model once, as FastAPI's form models are named::

    async def train_model(..., p: FaceTrainParams = params_form(FaceTrainParams, ', e.g. {"source": "synthetic"}')):

:func:`params_form` is the dependency that reads the field (422 ``invalid_parameters`` naming the problem); the
field's schema in FastAPI's document names the model (:data:`MODEL_KEY`), whose schema :mod:`app.openapi_doc` puts in
its place (:func:`declared_model`).
"""
from __future__ import annotations

from typing import Any, Callable, TypeVar

from fastapi import Depends, Form
from pydantic import BaseModel, ValidationError

from app.errors import ApiError
from workers.common.validation import describe_errors

M = TypeVar("M", bound=BaseModel)
MODEL_KEY = "x-params-model"
"""The key of a ``params`` field's schema that names its model."""
_DECLARED: dict[str, type[BaseModel]] = {}
"""Every model a route's ``params`` field was declared as, by name."""


def parse_params(model: type[M], text: str | None) -> M:
    """A request's ``params`` form field (a JSON object) as ``model``; 422 naming the problem otherwise."""
    try:
        # strict: the JSON types the schema documents (no true for 1, no "5" for 5); JSON still gives
        # floats from integers, enums from strings and tuples from arrays.
        return model.model_validate_json(text or "{}", strict=True)
    except ValidationError as exc:
        if any(e["type"] == "json_invalid" for e in exc.errors()):
            raise ApiError(422, f"params must be a JSON object: {exc.errors()[0]['msg']}", "invalid_parameters") from None
        raise ApiError(422, f"invalid parameters: {describe_errors(exc)}", "invalid_parameters") from None


def params_form(model: type[M], detail: str = "", *, required: bool = False) -> Any:
    """The route's ``params`` form field read as ``model`` (a parameter's default: ``p: Model = params_form(Model)``).

    ``detail``: what the field's description says after "JSON object of <Model>" (an example, the default);
    ``required``: the field must be sent (else it may be left out, which reads as ``{}``). The field's schema names
    the model (:data:`MODEL_KEY`)."""
    if _DECLARED.setdefault(model.__name__, model) is not model:
        raise ValueError(f"two params models are called {model.__name__}; rename one")
    field = {"description": f"JSON object of {model.__name__}{detail}",
             "json_schema_extra": {MODEL_KEY: model.__name__}}
    parse: Callable[..., M]
    if required:
        def parse(params: str = Form(..., **field)) -> M:
            return parse_params(model, params)
    else:
        def parse(params: str | None = Form(None, **field)) -> M:
            return parse_params(model, params)
    return Depends(parse)


def declared_model(name: str) -> type[BaseModel] | None:
    """The model a route's ``params`` field named ``name`` (its schema's :data:`MODEL_KEY`) was declared as."""
    return _DECLARED.get(name)
