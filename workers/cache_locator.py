"""numba's cache locator for our kernels (see :mod:`workers.portable_cache`; imported by numba itself)."""
from __future__ import annotations

from pathlib import Path

from numba.core.caching import UserProvidedCacheLocator

from workers.portable_cache import PACKAGE_ROOT


class PortableLocator(UserProvidedCacheLocator):
    """numba's ``NUMBA_CACHE_DIR`` locator, with the folder named after the source's path inside this project
    (``workers/sweep/kernels.py`` -> ``<cache>/workers_sweep``) rather than after a hash of its absolute path.
    Sources elsewhere are left to numba's own locators."""

    @classmethod
    def from_function(cls, py_func, py_file):  # noqa: ANN001, ANN206 - numba's signature
        try:
            Path(py_file).resolve().relative_to(PACKAGE_ROOT / "workers")
        except ValueError:
            return None
        return super().from_function(py_func, py_file)

    @classmethod
    def get_suitable_cache_subpath(cls, py_file):  # noqa: ANN001, ANN206 - numba's signature
        return "_".join(Path(py_file).resolve().parent.relative_to(PACKAGE_ROOT).parts)
