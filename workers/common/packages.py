"""Installed distributions' versions, for keys and reports that must change when a dependency does."""
from __future__ import annotations


def package_version(distribution: str) -> str | None:
    """The installed version of ``distribution`` (a PyPI name), None when it is not installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(distribution)
    except PackageNotFoundError:
        return None
