"""Writing measured results: ``benchmarks/results/<name>.json`` and a section of RESULTS.md.

Every benchmark script ends with :func:`publish`, which stamps the machine, the date and the
exact command line on both, so that every figure in RESULTS.md says where it came from.
"""
from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import re
import shlex
import sys
from pathlib import Path
from typing import Any

BENCH_DIR = Path(__file__).resolve().parent
RESULTS_DIR = BENCH_DIR / "results"
RESULTS_MD = BENCH_DIR / "RESULTS.md"
_HEADER = (
    "# Benchmark results\n\n"
    "Written by the scripts in `benchmarks/` from measured runs; do not edit by hand.\n"
    "Each section names the machine, the date and the exact command that produced it.\n"
)


def machine() -> dict[str, Any]:
    """A short description of the machine the run happened on."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem_gb = None
    try:
        pages = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        mem_gb = round(pages / 2**30, 1)
    except (ValueError, OSError):
        pass
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "memory_gb": mem_gb,
        "python": platform.python_version(),
        "os": platform.platform(terse=True),
    }


def command_line() -> str:
    """The command that started this process, as a person would type it."""
    script = os.path.relpath(sys.argv[0], BENCH_DIR.parent) if sys.argv else "?"
    return "python " + " ".join(shlex.quote(a) for a in [script, *sys.argv[1:]])


def publish(name: str, results: dict[str, Any], markdown: str) -> Path:
    """Write ``results/<name>.json`` and replace the ``<name>`` section of RESULTS.md.

    ``markdown`` is the body of the section (tables, notes); the heading and the
    machine/date/command stamp are added here.
    """
    stamp = {
        "machine": machine(),
        "date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "command": command_line(),
    }
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    out = RESULTS_DIR / f"{name}.json"
    tmp = out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps({"meta": stamp, **results}, indent=2, default=_jsonable) + "\n")
    tmp.replace(out)

    m = stamp["machine"]
    section = (
        f"<!-- begin {name} -->\n## {name}\n\n"
        f"Machine: {m['cpu']}, {m['cores']} cores, {m['memory_gb']} GB, Python {m['python']}. "
        f"Date: {stamp['date']}. Command: `{stamp['command']}`\n\n"
        f"{markdown.strip()}\n<!-- end {name} -->\n"
    )
    text = RESULTS_MD.read_text() if RESULTS_MD.exists() else _HEADER
    pattern = re.compile(rf"<!-- begin {re.escape(name)} -->.*?<!-- end {re.escape(name)} -->\n", re.S)
    if pattern.search(text):
        text = pattern.sub(lambda _: section, text)
    else:
        text = text.rstrip("\n") + "\n\n" + section
    RESULTS_MD.write_text(text)
    return out


def _jsonable(value: Any) -> Any:
    try:
        import numpy as np

        if isinstance(value, np.generic):
            return value.item()
        if isinstance(value, np.ndarray):
            return value.tolist()
    except ImportError:  # pragma: no cover
        pass
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON-serialisable: {type(value).__name__}")


def md_table(headers: list[str], rows: list[list[Any]]) -> str:
    """A Markdown table; floats are shown with 3 significant decimals."""
    def fmt(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.3g}" if abs(v) < 1e-2 or abs(v) >= 1e4 else f"{v:.3f}".rstrip("0").rstrip(".")
        return str(v)

    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)
