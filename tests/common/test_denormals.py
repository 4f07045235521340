"""Denormals flushed while a network runs (workers/common/denormals.py): on, off again after, on this thread only."""
from __future__ import annotations

import platform
import threading

import numpy as np
import pytest

from workers.common.denormals import flushed_denormals, supported

TINY = np.float32(1e-39)  # below float32's smallest normal number (1.18e-38): a denormal
ON_GLIBC_X86_OR_ARM = (platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"
                       and platform.machine().lower() in ("x86_64", "amd64", "aarch64", "arm64"))


def _denormal_product() -> float:
    """A product of normal numbers whose result is a denormal (1e-20 x 1e-19 = 1e-39), and a denormal input halved."""
    a = np.array([1e-20], dtype=np.float32)
    b = np.array([1e-19], dtype=np.float32)
    return float((a * b)[0] + (np.array([TINY]) * np.float32(0.5))[0])


def test_supported_on_the_platforms_the_service_runs_on():
    assert supported() is ON_GLIBC_X86_OR_ARM


@pytest.mark.skipif(not ON_GLIBC_X86_OR_ARM, reason="flushing is only known for glibc on x86-64 and AArch64")
def test_denormals_are_zero_inside_and_back_after():
    assert _denormal_product() > 0  # IEEE 754 gradual underflow
    with flushed_denormals() as on:
        assert on
        assert _denormal_product() == 0.0
        normal = np.float32(3.0) * np.float32(1e-30)
        assert normal == np.float32(3e-30)  # normal numbers are untouched
    assert _denormal_product() > 0


@pytest.mark.skipif(not ON_GLIBC_X86_OR_ARM, reason="flushing is only known for glibc on x86-64 and AArch64")
def test_nested_blocks_restore_flushing_of_the_outer_one():
    with flushed_denormals():
        with flushed_denormals():
            assert _denormal_product() == 0.0
        assert _denormal_product() == 0.0
    assert _denormal_product() > 0


@pytest.mark.skipif(not ON_GLIBC_X86_OR_ARM, reason="flushing is only known for glibc on x86-64 and AArch64")
def test_another_thread_keeps_gradual_underflow():
    inside, started, release = [], threading.Event(), threading.Event()

    def flushing_thread():
        with flushed_denormals():
            inside.append(_denormal_product())
            started.set()
            release.wait(5)

    worker = threading.Thread(target=flushing_thread)
    worker.start()
    try:
        assert started.wait(5)
        assert inside == [0.0]
        assert _denormal_product() > 0  # this thread, while the other one flushes
    finally:
        release.set()
        worker.join()


@pytest.mark.skipif(not ON_GLIBC_X86_OR_ARM, reason="flushing is only known for glibc on x86-64 and AArch64")
def test_an_error_inside_still_restores():
    with pytest.raises(RuntimeError):
        with flushed_denormals():
            raise RuntimeError("a network failed")
    assert _denormal_product() > 0


def test_the_text_gate_leaves_the_callers_arithmetic_as_it_found_it():
    from workers.orientation.textlines import get_line_detector

    page = np.full((240, 320), 255, np.uint8)
    page[100:110, 40:280] = 0
    get_line_detector().probability(page, 320)
    assert _denormal_product() > 0
