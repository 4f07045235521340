"""The compiled depth searches under stress, each run in a subprocess: a memory error (the process ends
with a signal) fails this test instead of killing the test runner. See :mod:`harness.kernel_stress`."""
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("threads", [1, 2, 4])
def test_every_search_variant_equals_the_reference_on_random_misaligned_rigs(threads):
    env = {**os.environ, "NUMBA_NUM_THREADS": "4"}
    proc = subprocess.run([sys.executable, "-m", "harness.kernel_stress", "--reps", "100", "--threads",
                           str(threads), "--seed", str(100 + threads)], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=600)
    if proc.returncode < 0:
        pytest.fail(f"the kernels died with {signal.Signals(-proc.returncode).name} at {threads} threads:\n"
                    f"{proc.stderr[-3000:]}")
    assert proc.returncode == 0, proc.stdout + proc.stderr[-3000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert report["reps"] == 100 and report["variance_searches_unequal"] == 0
    assert report["pixels_with_depth"] > 0.2  # the random rigs do see the views
