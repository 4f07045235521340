"""Cluster scenarios: scripts that start a local Ray cluster and the service in a fresh process (a test's own Ray
must not be the one they start), run one job and print one JSON line; the tests run them and read that line."""
from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def wait_ready(client: Any, deadline: float) -> None:
    """Poll ``/readyz`` through ``client`` (a TestClient) until it answers 200; SystemExit after ``deadline``
    (``time.monotonic()``)."""
    while client.get("/readyz").status_code != 200:
        if time.monotonic() > deadline:
            raise SystemExit("not ready")
        time.sleep(0.1)


def wait_job(client: Any, job_id: str, deadline: float, poll_s: float = 0.1) -> dict[str, Any]:
    """The job's record once it has succeeded or failed; SystemExit naming its state after ``deadline``."""
    while (state := client.get(f"/v1/jobs/{job_id}").json())["state"] not in ("succeeded", "failed"):
        if time.monotonic() > deadline:
            raise SystemExit(f"job stuck: {state}")
        time.sleep(poll_s)
    return state


def run_scenario(script: str, timeout_s: float) -> dict[str, Any]:
    """Run ``script`` (a path from the repository root) in a fresh interpreter; the JSON of its last line. Fails
    with the end of its stderr when it exits non-zero."""
    out = subprocess.run([sys.executable, str(ROOT / script)], capture_output=True, text=True, timeout=timeout_s,
                         cwd=ROOT)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])
