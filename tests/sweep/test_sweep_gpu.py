"""The GPU depth search (workers/sweep/gpu.py): the same choice as the CPU search, and a renderer that
never fails for want of a GPU. The kernels run through numba's CUDA simulator on machines without a GPU
(in a subprocess: the simulator must be chosen before numba's CUDA target is imported), and on the GPU
itself, at a realistic size, where there is one."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from workers.sweep import renderer as renderer_module
from workers.sweep.renderer import RenderOptions, SweepRenderer

ROOT = Path(__file__).resolve().parents[2]


def _check(env_extra: dict[str, str], *args: str) -> dict:
    env = {**os.environ, **env_extra}
    proc = subprocess.run([sys.executable, "-W", "ignore", "-m", "tests.sweep.gpu_check", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout + proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _assert_agrees(report: dict, min_same_plane: float) -> None:
    assert report["device"] == "cuda"
    assert report["votes_equal"] > 0.97  # cameras seeing a point: differs only where one sits on an image edge
    assert report["ssd_rel_diff_median"] < 0.01
    for name, case in report["cases"].items():
        assert case["same_found"] > 0.97, name
        assert case["same_filled"] > 0.97, name  # the occlusion fill's cross-view check on the GPU's volume
        assert case["within_one_plane"] > 0.97, name
        assert case["same_plane"] > min_same_plane, name
        assert case["psnr_gpu_vs_cpu"] > 30.0, name


def test_gpu_kernels_choose_the_cpu_planes_in_the_simulator():
    report = _check({"NUMBA_ENABLE_CUDASIM": "1"}, "--width", "16", "--height", "12", "--cameras", "3",
                    "--planes", "5", "--cases", "none,window")
    _assert_agrees(report, 0.85)
    assert report["cases"]["window"]["pixels_with_depth"] > 0.5


@pytest.mark.skipif(not (os.path.exists("/dev/nvidiactl") and renderer_module.wants_gpu("auto")),
                    reason="no CUDA GPU here")
def test_gpu_matches_the_cpu_on_a_real_gpu():
    report = _check({}, "--width", "160", "--height", "120", "--cameras", "6", "--planes", "48")
    _assert_agrees(report, 0.9)


def test_cpu_device_never_loads_the_gpu_target(capture):
    _, rig, views = capture
    r = SweepRenderer(rig, [v.image for v in views], device="cpu")
    assert r.device == "cpu" and r._gpu is None


def test_unknown_device_is_refused(capture, monkeypatch):
    _, rig, views = capture
    with pytest.raises(ValueError, match="device must be"):
        SweepRenderer(rig, [v.image for v in views], device="tpu")
    monkeypatch.setenv("SWEEPCAST_SWEEP_DEVICE", "opencl")
    with pytest.raises(ValueError, match="sweep_device"):
        SweepRenderer(rig, [v.image for v in views])


@pytest.mark.skipif(os.path.exists("/dev/nvidiactl"), reason="this machine has an NVIDIA driver")
def test_auto_without_a_gpu_is_the_cpu(capture, monkeypatch):
    _, rig, views = capture
    monkeypatch.delenv("SWEEPCAST_SWEEP_DEVICE", raising=False)
    assert SweepRenderer(rig, [v.image for v in views]).device == "cpu"


def test_a_failing_gpu_leaves_the_render_to_the_cpu(capture, between_camera):
    """A GPU that breaks at its first use (a driver without NVVM, say) costs nothing but the log line."""
    _, rig, views = capture

    class BrokenGpu:
        def choose(self, *args, **kwargs):
            raise RuntimeError("CUDA_ERROR_NO_BINARY_FOR_GPU")

        def set_frames(self, *args):
            pass

    r = SweepRenderer(rig, [v.image for v in views], device="cpu")
    opt = RenderOptions(planes=24, near=1.6, far=3.6)
    expected = r.render(between_camera, opt)
    r._gpu, r.device = BrokenGpu(), "cuda"
    got = r.render(between_camera, opt)
    assert r.device == "cpu" and r._gpu is None
    assert np.array_equal(got.image, expected.image) and np.array_equal(got.plane_index, expected.plane_index)

