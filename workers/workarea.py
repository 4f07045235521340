"""A job's work area: the part of the blob store its tasks share, across processes, nodes and attempts.

A job that fans out (:mod:`workers.fanout`) hands each of its tasks a :class:`WorkArea`: a small picklable handle
(the store's URL, the area's prefix, by default ``jobs/<id>/work``, and the job's inputs' keys) that any process of
the cluster opens once. Through it

- a task on any node reads the job's inputs and what another node's task wrote (the store is shared: a directory on
  a shared volume or an object store), and the job's own process never has to hold it all;
- the job publishes files its tasks wrote as results (:meth:`workers.runtime.StoreJobContext.adopt_result`) without
  their bytes passing through its own process;
- an attempt that follows a lost worker or a restarted service finds what the earlier attempt finished and goes on
  from there (a task's output, written atomically, is its own proof; a stage may record itself done).

The area is deleted once the job's results are published, and with the job. :class:`InputRef` names one job input
as a file any node can open (an object store's copy is downloaded once per process).
"""
from __future__ import annotations

import functools
import io
import json
import pickle
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from workers.storage import BlobNotFound, BlobStore, DirectoryBlobStore, check_key, open_store


def work_prefix(job_id: str) -> str:
    """The blob-store prefix of a job's work area."""
    return f"jobs/{job_id}/work"


@functools.lru_cache(maxsize=8)
def _store_at(url: str) -> BlobStore:
    """The store at ``url``, opened once per process (an object store's client is costly to make)."""
    return open_store(url)


@dataclass(frozen=True)
class InputRef:
    """A job input readable on every node: its blob ``key`` in the store at ``store_url``, or a local ``path``
    (the command line, where every task runs in the one process); ``name`` is what messages call it."""

    name: str
    store_url: str | None = None
    key: str | None = None
    path: str | None = None

    def local_path(self) -> Path:
        """A file on this node holding the input."""
        if self.path is not None:
            return Path(self.path)
        assert self.store_url is not None and self.key is not None
        return _store_at(self.store_url).local_path(self.key)


@dataclass
class WorkArea:
    """Named blobs below ``prefix`` of the store at ``store_url``, and the job's ``inputs`` (see the module
    docstring). Names are ``/``-separated like blob keys (letters, digits, ``._-``)."""

    store_url: str
    prefix: str
    inputs: dict[str, str] = field(default_factory=dict)
    """Input name -> blob key, as the job's context has them."""
    opened: BlobStore | None = field(default=None, compare=False, repr=False)
    """The store already open in this process (left out when pickled: another process opens its own)."""

    @classmethod
    def for_job(cls, store: BlobStore, job_id: str, inputs: dict[str, str]) -> "WorkArea":
        """The work area of job ``job_id`` in ``store`` (open in this process), with the job's ``inputs``."""
        return cls(store.url, work_prefix(job_id), dict(inputs), opened=store)

    @classmethod
    def in_folder(cls, folder: str | Path) -> "WorkArea":
        """A work area in a local folder (a directory store rooted there: the command line, tests)."""
        store = DirectoryBlobStore(folder)
        return cls(store.url, "work", opened=store)

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "opened": None}

    @property
    def store(self) -> BlobStore:
        if self.opened is None:
            self.opened = _store_at(self.store_url)
        return self.opened

    def key(self, name: str) -> str:
        """The blob key of work file ``name`` (a relative key: ``entries/000012.json``)."""
        return f"{self.prefix}/{check_key(name)}"

    def read_input(self, name: str) -> bytes:
        """The bytes of the job's input ``name``."""
        key = self.inputs.get(name)
        if key is None:
            raise KeyError(f"this job has no input named {name!r}")
        return self.store.read(key)

    def exists(self, name: str) -> bool:
        return self.store.exists(self.key(name))

    def put(self, name: str, data: bytes) -> int:
        """Write ``name`` atomically (a reader sees all of it or nothing); its size in bytes."""
        return self.store.put(self.key(name), data)

    def get(self, name: str) -> bytes:
        """The bytes of ``name``; :class:`~workers.storage.BlobNotFound` (a KeyError) when no task wrote it."""
        return self.store.read(self.key(name))

    def names(self, folder: str) -> list[str]:
        """The work files below ``folder`` (names relative to the work area, sorted)."""
        start = self.prefix + "/"
        return [key[len(start):] for key in self.store.list(f"{start}{check_key(folder)}")]

    def put_arrays(self, name: str, **arrays: np.ndarray) -> int:
        """Write numpy arrays as one ``.npz`` blob (not compressed: depth maps and points hardly compress, and
        zlib would cost a survey's tasks more time than the store saves them)."""
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        return self.put(name, buf.getvalue())

    def get_arrays(self, name: str) -> dict[str, np.ndarray]:
        """The arrays :meth:`put_arrays` wrote under ``name``."""
        with np.load(io.BytesIO(self.get(name)), allow_pickle=False) as data:
            return {k: data[k] for k in data.files}

    def put_json(self, name: str, value: Any) -> int:
        return self.put(name, json.dumps(value).encode())

    def get_json(self, name: str) -> Any:
        return json.loads(self.get(name))

    def put_object(self, name: str, value: Any) -> int:
        """Write a Python object (a stage's state, as the job's own code made it; pickled as Ray sends task
        arguments: this store is the service's own, never written by a user)."""
        return self.put(name, pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))

    def get_object(self, name: str) -> Any:
        return pickle.loads(self.get(name))

    def clear(self) -> None:
        """Delete everything in the work area."""
        self.store.delete_prefix(self.prefix)


__all__ = ["BlobNotFound", "InputRef", "WorkArea", "work_prefix"]
