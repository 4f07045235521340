"""Single-threaded BLAS for the face engine.

Its matrix products are small (a few hundred rows, or one vector against a (3N, K) basis): BLAS
threads only add synchronisation, which on busy cores makes them many times slower than one thread.
"""
from __future__ import annotations

import functools
from contextlib import contextmanager
from typing import Iterator

from threadpoolctl import ThreadpoolController


@functools.cache
def _controller() -> ThreadpoolController:
    return ThreadpoolController()  # inspecting the loaded libraries costs ~0.4 ms: do it once


@contextmanager
def single_threaded() -> Iterator[None]:
    """Limit BLAS to one thread inside the block (also usable as a decorator)."""
    with _controller().limit(limits=1, user_api="blas"):
        yield
