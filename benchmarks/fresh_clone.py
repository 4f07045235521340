"""The whole test suite, several times in a row, in a fresh clone of the committed tree.

    python -m benchmarks.fresh_clone [--runs 3]

Clones HEAD of this repository into a temporary folder (nothing uncommitted comes along, no .venv, no
numba cache) and runs the README's test command (`make test`) there ``--runs`` times; the first run
makes the virtual environment. A run that ends with a signal (a crash) or a failed test fails the
section. The clone has no benchmark data beside it (as in CI), so the data tests skip.
"""
from __future__ import annotations

import argparse
import re
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

from benchmarks._report import md_table, prog, publish

ROOT = Path(__file__).resolve().parents[1]

_COUNTS = re.compile(r"(\d+) (passed|failed|skipped|errors?|xfailed|xpassed|deselected)")


def pytest_counts(output: str) -> dict[str, int]:
    """Counts from pytest's closing line ("734 passed, 1 skipped in 222.55s")."""
    closing = [line for line in output.splitlines() if re.search(r" in [\d.]+s", line) and _COUNTS.search(line)]
    return {kind.rstrip("s") if kind.startswith("error") else kind: int(n)
            for n, kind in _COUNTS.findall(closing[-1])} if closing else {}


def run_suite(clone: Path) -> dict:
    t0 = time.perf_counter()
    proc = subprocess.run(["make", "test"], cwd=clone, capture_output=True, text=True)
    # make reports a child killed by a signal as "Error 139" (128 + SIGSEGV) or "Segmentation fault"
    died = re.search(r"Error (1[3-5]\d)\b|Segmentation fault|Fatal Python error", proc.stdout + proc.stderr)
    counts = pytest_counts(proc.stdout)
    return {"exit_code": proc.returncode, "seconds": time.perf_counter() - t0, **counts,
            "crashed": bool(died), "signal": _signal_name(died.group(1)) if died and died.group(1) else None,
            "tail": (proc.stdout + proc.stderr)[-1500:] if proc.returncode else ""}


def _signal_name(code: str) -> str:
    try:
        return signal.Signals(int(code) - 128).name
    except ValueError:
        return code


def main() -> int:
    ap = argparse.ArgumentParser(prog=prog(), description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args()
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout.strip()
    base = Path(tempfile.mkdtemp(prefix="sc-fresh-"))
    clone = base / "sweepcast"
    try:
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        runs = []
        for k in range(args.runs):
            runs.append(run_suite(clone))
            print(f"  run {k + 1}: exit {runs[-1]['exit_code']}, {runs[-1].get('passed', 0)} passed, "
                  f"{runs[-1].get('failed', 0)} failed ({runs[-1]['seconds']:.0f} s)", flush=True)
    finally:
        shutil.rmtree(base, ignore_errors=True)
    ok = all(r["exit_code"] == 0 and not r["crashed"] for r in runs)
    rows = [[k + 1, r["exit_code"], r.get("passed", 0), r.get("failed", 0), r.get("skipped", 0), r.get("error", 0),
             r["signal"] or ("yes" if r["crashed"] else "no"), round(r["seconds"])] for k, r in enumerate(runs)]
    body = (f"`make test` (the README's test command) {len(runs)} times in a row in a fresh clone of commit {head} "
            f"(no benchmark data beside it, as in CI: the data tests skip; the first run also makes the venv): "
            f"**{'all passed' if ok else 'NOT all passed'}**.\n\n"
            + md_table(["run", "exit", "passed", "failed", "skipped", "errors", "crash", "s"], rows))
    publish("fresh_clone", {"commit": head, "runs": runs, "all_passed": ok}, body)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
