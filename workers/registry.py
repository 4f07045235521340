"""The job kinds the workers run: kind name -> entry point and parameter model.

The web layer validates a job's parameters with the kind's pydantic model before it commits
the row, and the worker runtime validates them again before running (a row may come from an
older version). Entries are imported lazily so that a worker only loads the engine it runs.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any, Callable

from pydantic import BaseModel


@dataclass(frozen=True)
class JobKind:
    name: str
    entry: str
    """``module:function`` taking a JobContext and returning a JSON-able summary."""
    params: str
    """``module:Class``, the pydantic model of the parameters."""
    num_cpus: float = 1.0

    def load_entry(self) -> Callable[[Any], dict]:
        return _load(self.entry)

    def load_params(self) -> type[BaseModel]:
        return _load(self.params)

    def validate(self, params: dict[str, Any]) -> dict[str, Any]:
        """The parameters with defaults filled in; raises pydantic.ValidationError."""
        return self.load_params().model_validate(params).model_dump(mode="json")


def _load(path: str) -> Any:
    module, _, attr = path.partition(":")
    return getattr(importlib.import_module(module), attr)


JOB_KINDS: dict[str, JobKind] = {
    kind.name: kind
    for kind in [
        JobKind(
            "orientation.batch",
            "workers.orientation.job:run_orientation_batch",
            "workers.orientation.job:OrientationBatchParams",
        ),
        JobKind("depth.video", "workers.depth.job:run_depth_video", "workers.depth.params:DepthVideoParams"),
        JobKind("streaming.recording", "workers.streaming.job:run_recording_import",
                "workers.streaming.params:RecordingImportParams"),
        JobKind("streaming.render", "workers.streaming.job:run_batch_render", "workers.streaming.params:BatchRenderParams"),
        JobKind("streaming.demo", "workers.streaming.job:run_demo_recording", "workers.streaming.params:DemoParams"),
        JobKind("faces.train", "workers.faces.job:run_face_training", "workers.faces.job:FaceTrainParams"),
        JobKind("drone.reconstruct", "workers.drone.job:run_reconstruction", "workers.drone.params:ReconstructionParams"),
    ]
}


def get_kind(name: str) -> JobKind:
    try:
        return JOB_KINDS[name]
    except KeyError:
        raise KeyError(f"unknown job kind {name!r}; known: {', '.join(sorted(JOB_KINDS))}") from None
