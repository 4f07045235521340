"""A job's work area: the part of the blob store its tasks share, across processes, nodes and attempts.

A job that fans out (:mod:`workers.fanout`) hands each of its tasks a :class:`WorkArea`: a small picklable handle
(the store's URL, the job's id and its inputs' keys) that any process of the cluster opens. A task reads its inputs
through it and writes what it made below ``jobs/<id>/work/``; the job then publishes those files as results
(:meth:`workers.runtime.StoreJobContext.adopt_result`) without their bytes passing through the job's own process.
The area outlives an attempt: a job resubmitted after a lost worker or a restart of the service finds what the
earlier attempt's tasks finished there (its tasks write each file atomically, their record of what they did last).
It is deleted once the job's results are published, and with the job.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

from workers.storage import BlobNotFound, BlobStore, check_key, open_store


def work_prefix(job_id: str) -> str:
    """The blob-store prefix of a job's work area."""
    return f"jobs/{job_id}/work"


_opened: dict[str, BlobStore] = {}
_opened_lock = threading.Lock()


def _store_at(url: str) -> BlobStore:
    """The store at ``url``, opened once per process (an object store's client is costly to make)."""
    with _opened_lock:
        if url not in _opened:
            _opened[url] = open_store(url)
        return _opened[url]


@dataclass
class WorkArea:
    """A job's inputs and work area, usable in any process (pickled with a task; see the module docstring)."""

    store_url: str
    job_id: str
    inputs: dict[str, str]
    """Input name -> blob key, as the job's context has them."""
    store: BlobStore | None = field(default=None, compare=False)
    """The store already open in this process (left out when pickled: another process opens its own)."""

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "store": None}

    def _store(self) -> BlobStore:
        if self.store is None:
            self.store = _store_at(self.store_url)
        return self.store

    def key(self, name: str) -> str:
        """The blob key of work file ``name`` (a relative key: ``entries/000012.json``)."""
        return f"{work_prefix(self.job_id)}/{check_key(name)}"

    def read_input(self, name: str) -> bytes:
        """The bytes of input ``name``."""
        key = self.inputs.get(name)
        if key is None:
            raise KeyError(f"job {self.job_id} has no input named {name!r}")
        return self._store().read(key)

    def put(self, name: str, data: bytes) -> int:
        """Write work file ``name`` (atomically: a reader sees the whole file or none); its size in bytes."""
        return self._store().put(self.key(name), data)

    def get(self, name: str) -> bytes | None:
        """Work file ``name``, None when no task wrote it."""
        try:
            return self._store().read(self.key(name))
        except BlobNotFound:
            return None

    def names(self, folder: str) -> list[str]:
        """The work files below ``folder`` (names relative to the work area, sorted)."""
        prefix = work_prefix(self.job_id) + "/"
        return [key[len(prefix):] for key in self._store().list(f"{prefix}{check_key(folder)}")]
