"""A numba kernel cache that every install of the same sources can use, and the CPU targets it is built for.

numba keys each cached kernel by the SHA-256 of its source file, the argument types, its own and Python's
versions and the CPU it was compiled for (LLVM's CPU name and feature string), all of which travel with the
sources. It files them, though, under a folder named after a hash of the source file's *absolute directory*,
so a cache compiled in one checkout, virtual environment or image path is invisible to any other.
:class:`workers.cache_locator.PortableLocator` files our kernels under their package path instead (``workers/sweep/x.py`` ->
``workers_sweep``), so a cache compiled ahead (by ``sweepcast warmup``, in an image build, on another machine)
serves any install of the same code. numba uses it when ``NUMBA_CACHE_DIR`` is set (the service always sets it);
:func:`register` puts it first in numba's list of locators, before any kernel module is imported.

A cache is compiled for one CPU target. numba compiles for the host CPU unless ``NUMBA_CPU_NAME`` and
``NUMBA_CPU_FEATURES`` name another; a cache meant for other machines is compiled for a baseline that they all
run (:data:`TARGETS`) and is loaded only by processes that set the same target (:func:`target_env`), on a CPU
that has every feature of it (:func:`host_supports`): anything else would stop at an illegal instruction.

This module never imports numba (numba reads those variables once, when it is imported).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

PACKAGE_ROOT = Path(__file__).resolve().parent.parent
"""The folder holding the ``workers`` package: cache folders are named relative to it."""

SHIPPED = PACKAGE_ROOT / "workers" / "_prebuilt"
"""What a wheel built by ``make wheel`` (``packaging/build-wheel.sh``) carries: ``kernels/`` (every engine's, compiled
for a portable target) and ``demo/`` (the demo rig's recording). A source checkout has none of it."""
SHIPPED_KERNELS = SHIPPED / "kernels"
SHIPPED_DEMO = SHIPPED / "demo"

STAMP_NAME = "warmed.json"
"""Written into the cache by a warm-up of every engine that succeeded (:mod:`workers.warmup`): the fingerprint it
warmed and the CPU target it compiled for (``cpu_name``, ``cpu_features``)."""

_X86_64_V2 = ("cmov", "cx8", "fxsr", "mmx", "sse", "sse2", "cx16", "sahf", "popcnt", "sse3", "sse4.1", "sse4.2",
              "ssse3")
TARGETS: dict[str, tuple[str, ...]] = {
    # x86-64-v3 (AVX2, FMA, BMI1/2; every x86-64 server CPU since Intel Haswell, 2013, and AMD Zen, 2017)
    "x86-64-v3": (*_X86_64_V2, "avx", "avx2", "bmi", "bmi2", "f16c", "fma", "lzcnt", "movbe", "xsave"),
}
"""Portable CPU targets: LLVM's CPU name -> the features it requires (LLVM's names)."""


def target_features(name: str) -> str:
    """``NUMBA_CPU_FEATURES`` for the target ``name`` (a key of :data:`TARGETS`): its features, each enabled."""
    return ",".join(f"+{f}" for f in TARGETS[name])


def target_env(name: str) -> dict[str, str]:
    """The environment that makes numba compile for, and load kernels compiled for, the target ``name``."""
    return {"NUMBA_CPU_NAME": name, "NUMBA_CPU_FEATURES": target_features(name)}


def host_cpu() -> tuple[str, str]:
    """This CPU as LLVM names it: (CPU name, feature string ``+a,-b,...``), what numba compiles for by default."""
    import llvmlite.binding as ll

    try:
        features = ll.get_host_cpu_features().flatten()
    except RuntimeError:
        features = ""
    return ll.get_host_cpu_name(), features


def host_supports(name: str) -> list[str]:
    """The features of the target ``name`` that this CPU lacks (empty: it runs that target's code)."""
    enabled = {f[1:] for f in host_cpu()[1].split(",") if f.startswith("+")}
    return [f for f in TARGETS[name] if f not in enabled]


def configured_target() -> tuple[str, str]:
    """The CPU target numba compiles for in this process: ``NUMBA_CPU_NAME`` / ``NUMBA_CPU_FEATURES`` where set
    (as numba reads them when it is imported), else this CPU."""
    name, features = host_cpu()
    return os.environ.get("NUMBA_CPU_NAME") or name, os.environ.get("NUMBA_CPU_FEATURES", features)


def register() -> None:
    """Make numba file our cached kernels with :class:`workers.cache_locator.PortableLocator` (numba's own
    locators after it; an operator's ``NUMBA_CACHE_LOCATOR_CLASSES`` wins). Must
    run before a kernel module is imported: numba picks a function's locator when it is decorated."""
    entry = "workers.cache_locator.PortableLocator"
    defaults = "UserProvidedCacheLocator,InTreeCacheLocator,UserWideCacheLocator,IPythonCacheLocator,ZipCacheLocator"
    chosen = os.environ.get("NUMBA_CACHE_LOCATOR_CLASSES") or f"{entry},{defaults}"
    os.environ["NUMBA_CACHE_LOCATOR_CLASSES"] = chosen
    config = sys.modules.get("numba.core.config")
    if config is not None:  # numba already read its environment: tell it too
        config.CACHE_LOCATOR_CLASSES = chosen
