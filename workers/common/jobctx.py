"""The contract between the job system and an engine's job entry point.

An engine's job function has the signature ``run(ctx: JobContext) -> dict`` and is declared with
its parameter model as a :class:`workers.registry.JobKind` in ``workers/<engine>/job.py``. It reads
its inputs and parameters from ``ctx`` (``ctx.params`` is the kind's pydantic model, validated once by
the runtime; ``Model.model_validate`` returns such an instance as it is, and validates the dicts that
tests and command-line contexts pass), reports progress with ``ctx.progress``, writes each
result file with ``ctx.write_result`` (or into ``ctx.result_path``), and returns a small
JSON-able summary that becomes part of the job's result manifest.

A job whose work grows with its input fans out: it splits the work into tasks and runs a module-level function
over them with ``ctx.fanout()`` (Ray tasks on every CPU of the cluster when the job runs on Ray; sized with its
``parallelism``); each task reads and writes through ``ctx.work_area()``, a handle on the job's inputs and its
work area in the blob store that any process opens, and the job publishes the files its tasks wrote with
``ctx.adopt_result``. The work area outlives an attempt, so a job run again after a lost worker can take up what
its tasks already finished.

A failure the user caused (a file that is not a video, absurd intrinsics, ...) is raised
as :class:`JobInputError` with a message a person understands: the job fails at once with
that message and is not retried. Any other exception is treated as a bug or a lost worker:
the job is retried and, when the retries are spent, fails with the exception's summary.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from workers.settings import WorkerSettings

if TYPE_CHECKING:
    from workers.fanout import FanOut
    from workers.workarea import InputRef, WorkArea


class JobInputError(Exception):
    """The job's input is unusable; the message is shown to the user as the job's error."""


class JobContext(Protocol):
    """What a job function sees of the job system (implemented by workers.runtime)."""

    job_id: str
    kind: str
    params: Any
    """The kind's parameter model (an instance of ``JobKind.params``)."""
    inputs: dict[str, str]
    """Input name -> blob key. Names are chosen by the API route (e.g. ``photo-0003``)."""
    input_meta: dict[str, dict[str, Any]]
    """Input name -> metadata recorded at upload (e.g. ``{"filename": "IMG_1.jpg", "size": 123}``)."""
    settings: WorkerSettings
    """The worker settings (limits, models, tools) the service passed to its workers: a job reads its limits
    here and hands them to the engine's functions as plain arguments."""

    def input_path(self, name: str) -> Path:
        """A local file holding input ``name`` (downloaded first when the store is remote)."""

    def read_input(self, name: str) -> bytes:
        """The bytes of input ``name``."""

    def result_path(self, name: str) -> Path:
        """A local path to write result ``name`` to; it is published when the job succeeds."""

    def write_result(self, name: str, data: bytes) -> None:
        """Write result ``name`` (published atomically with the others when the job succeeds)."""

    def progress(self, fraction: float, stage: str, *, done: int | None = None, total: int | None = None,
                 eta_s: float | None = None) -> None:
        """Report progress: ``fraction`` in [0, 1] of the whole job, ``stage`` a short text; a job that counts items
        also says how many are ``done`` of ``total`` and the seconds it expects to need still (``eta_s``, None
        before it can tell)."""

    def fanout(self) -> "FanOut":
        """Where the job runs its parallel stages (:mod:`workers.fanout`): Ray tasks across the cluster when the job
        runs on Ray, else this process; ``fanout().parallelism`` says how many run at once."""

    def work_area(self) -> "WorkArea":
        """The job's inputs and its area for intermediate data, readable from every node and kept across its
        attempts (:mod:`workers.workarea`)."""

    def input_ref(self, name: str) -> "InputRef":
        """Input ``name`` as a task on any node reads it."""

    def adopt_result(self, name: str, work_name: str, size: int) -> None:
        """Publish work file ``work_name`` (``size`` bytes) as result ``name`` with the others."""
