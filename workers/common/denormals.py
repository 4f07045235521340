"""Denormal floats flushed to zero on the calling thread while a network runs.

A float network's activations fall, here and there, below float32's normal range (1.2e-38): GELU and sigmoid of large
negative inputs, products of small weights. Many x86 cores take a microcode assist on every such operand or result,
tens of times the cost of a normal multiply-add, and a convolution over a map full of them slows by several times: the
text-line gate's network (:mod:`workers.orientation.textlines`) took 193 ms of one core for a 480 x 384 copy on an
Intel Xeon (Sapphire Rapids) and 57 ms with denormals flushed, its probability map identical to the last bit; Tesseract's
reading of the same photos fell by a third to a half. Such tiny values carry nothing a detector's scores can see.

The CPU flushes them when two bits of its floating-point control register are set: FTZ (results) and DAZ (inputs) in
x86's MXCSR, FZ in AArch64's FPCR. The register belongs to a thread, so :func:`flushed_denormals` sets it around the
call and restores it after, leaving every other computation of the process (and of other threads) as IEEE 754 says.
onnxruntime's own ``session.set_denormal_as_zero`` option does the same only for its pool threads, not for the calling
thread that runs a one-thread session.

The register is read and written through the C library's ``fegetenv``/``fesetenv`` (glibc's ``fenv_t`` layout, on
x86-64 and AArch64 Linux); elsewhere the context does nothing and says so.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import platform
from contextlib import contextmanager
from functools import lru_cache
from typing import Callable, Iterator

_ENV_BYTES = 64
"""Room for the C library's ``fenv_t`` (32 bytes on x86-64, 8 on AArch64)."""
_X86_MXCSR_OFFSET = 28
"""glibc's x86-64 ``fenv_t``: the x87 environment (28 bytes), then MXCSR."""
_X86_FTZ_DAZ = (1 << 15) | (1 << 6)
_ARM_FPCR_FZ = 1 << 24
"""glibc's AArch64 ``fenv_t``: FPCR (its first 4 bytes), then FPSR."""


def _set_bits(offset: int, bits: int) -> Callable[[bytes], bytes]:
    def edit(env: bytes) -> bytes:
        word = int.from_bytes(env[offset:offset + 4], "little") | bits
        return env[:offset] + word.to_bytes(4, "little") + env[offset + 4:]
    return edit


@lru_cache(maxsize=1)
def _support() -> tuple[ctypes.CDLL, Callable[[bytes], bytes]] | None:
    """(the C maths library, how to set the flush bits in an environment), or None where that layout is not known."""
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return None
    machine = platform.machine().lower()
    if machine in ("x86_64", "amd64"):
        edit = _set_bits(_X86_MXCSR_OFFSET, _X86_FTZ_DAZ)
    elif machine in ("aarch64", "arm64"):
        edit = _set_bits(0, _ARM_FPCR_FZ)
    else:
        return None
    try:
        libm = ctypes.CDLL(ctypes.util.find_library("m") or "libm.so.6")
    except OSError:
        return None
    return libm, edit


def supported() -> bool:
    """Whether :func:`flushed_denormals` can flush on this platform (Linux with glibc, x86-64 or AArch64)."""
    return _support() is not None


@contextmanager
def flushed_denormals() -> Iterator[bool]:
    """Within the block, this thread's float operations treat denormal inputs and results as zero; the thread's
    floating-point environment (rounding, flags, exception masks) is restored as it was on leaving. Yields whether
    flushing is on (False where :func:`supported` is not: the block then runs as it would without)."""
    found = _support()
    saved = ctypes.create_string_buffer(_ENV_BYTES)
    if found is None or found[0].fegetenv(saved) != 0:
        yield False
        return
    libm, edit = found
    flushing = ctypes.create_string_buffer(edit(saved.raw), _ENV_BYTES)
    if libm.fesetenv(flushing) != 0:
        libm.fesetenv(saved)
        yield False
        return
    try:
        yield True
    finally:
        libm.fesetenv(saved)
