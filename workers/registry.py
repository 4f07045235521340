"""The job kinds the workers run.

Every engine exposes the same small surface in ``workers/<engine>/job.py``: its entry functions
``run_*(ctx)``, their pydantic parameter models, and one :class:`JobKind` constant per kind named
``<engine>.<verb>`` (e.g. ``depth.video``), listed in that module's ``JOBS``. A route passes the
constant to ``app.services.create_job``, so a reader goes from a route to its engine function in one
step; a worker finds a stored row's kind by its engine's name, importing only that engine.

Parameters are validated once at each end: the route parses the request into the kind's model, and
the worker runtime validates the stored row (it may come from an older version) and hands the model
to the job as ``ctx.params``.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any, Callable

from pydantic import BaseModel

ENGINES = ("orientation", "depth", "streaming", "faces", "drone")
"""The engines with job kinds: ``workers/<engine>/job.py`` defines ``JOBS``."""


@dataclass(frozen=True)
class JobKind:
    name: str
    """``<engine>.<verb>``: the engine's folder name, then what the job does."""
    entry: Callable[[Any], dict]
    """Takes a JobContext whose ``params`` is an instance of ``params``; returns a JSON-able summary."""
    params: type[BaseModel]
    num_cpus: float = 1.0

    def validate(self, params: dict[str, Any] | BaseModel) -> BaseModel:
        """``params`` as the kind's model (an instance of it is returned as is); raises pydantic.ValidationError."""
        return self.params.model_validate(params)


def get_kind(name: str) -> JobKind:
    """The kind called ``name`` (its engine's job module is imported on first use); KeyError naming the known
    engines otherwise."""
    engine = name.partition(".")[0]
    if engine in ENGINES:
        for kind in importlib.import_module(f"workers.{engine}.job").JOBS:
            if kind.name == name:
                return kind
    raise KeyError(f"unknown job kind {name!r}; the engines with jobs: {', '.join(ENGINES)}")

