"""Pydantic validation errors as one line a person reads: the one wording of every API answer, job
failure and command-line error about bad parameters."""
from __future__ import annotations

from typing import Any, Iterable, Mapping

from pydantic import ValidationError


def describe_errors(errors: ValidationError | Iterable[Mapping[str, Any]], what: str = "params",
                    skip_loc: int = 0) -> str:
    """``"a.b: message; c: message"``: each error's field path (its ``loc``, dotted) and message.

    errors: a pydantic ValidationError or its ``errors()`` list (FastAPI's RequestValidationError
    gives the list); what: the name shown for an error about the whole object (empty ``loc``);
    skip_loc: leading ``loc`` parts to leave out (FastAPI's "body"/"query"), kept when nothing is left.
    """
    items = errors.errors() if isinstance(errors, ValidationError) else errors
    parts = []
    for e in items:
        loc = [str(p) for p in e.get("loc", ())]
        parts.append(f"{'.'.join(loc[skip_loc:] or loc) or what}: {e.get('msg', '')}")
    return "; ".join(parts)
