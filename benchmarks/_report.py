"""Writing measured results: ``benchmarks/results/<name>.json`` and a section of RESULTS.md.

Every benchmark script ends with :func:`publish`, which stamps the machine, the date and the
exact command line on both, so that every figure in RESULTS.md says where it came from. A script with
several parts declares them as :class:`Sections`, which gives it ``--only NAME[,NAME]`` (re-run those, keep
the others of the previous results file) and ``--list``; a part that writes a results file of its own is a
:class:`Part` of the script (``Sections.part``).

Scripts run as modules from the repository root: ``python -m benchmarks.<name> --help``.
``SWEEPCAST_BENCH_RESULTS=<folder>`` writes ``<folder>/<name>.json`` and ``<folder>/RESULTS.md`` instead of
``benchmarks/results/`` and ``benchmarks/RESULTS.md`` (to try a script without touching the recorded figures).
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import re
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

BENCH_DIR = Path(__file__).resolve().parent
_OTHER_DIR = os.environ.get("SWEEPCAST_BENCH_RESULTS")
RESULTS_DIR = Path(_OTHER_DIR).resolve() if _OTHER_DIR else BENCH_DIR / "results"
RESULTS_MD = RESULTS_DIR / "RESULTS.md" if _OTHER_DIR else BENCH_DIR / "RESULTS.md"
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


def _main_module() -> str | None:
    """The module ``python -m`` ran (``benchmarks.sweep`` for its ``__main__``), None for a script run."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    return spec.name.removesuffix(".__main__") if spec is not None and spec.name else None


def prog() -> str | None:
    """The program name for a script's ``--help``: ``python -m benchmarks.x`` when run as a module."""
    module = _main_module()
    return f"python -m {module}" if module else None


def command_line() -> str:
    """The command that started this process, as a person would type it (``python -m benchmarks.x ...`` for a
    module run, ``python path/to/script.py ...`` otherwise)."""
    module = _main_module()
    start = ["-m", module] if module else [os.path.relpath(sys.argv[0], BENCH_DIR.parent) if sys.argv else "?"]
    return "python " + " ".join(shlex.quote(a) for a in [*start, *sys.argv[1:]])


def shown_path(path: Path) -> str:
    """A written file as RESULTS.md names it: relative to the repository root when inside it."""
    path = Path(path).resolve()
    return str(path.relative_to(BENCH_DIR.parent)) if path.is_relative_to(BENCH_DIR.parent) else str(path)


def stamp() -> dict[str, Any]:
    """The machine, the date and the command of this run."""
    return {
        "machine": machine(),
        "date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "command": command_line(),
    }


def publish(name: str, results: dict[str, Any], markdown: str) -> Path:
    """Write ``results/<name>.json`` and replace the ``<name>`` section of RESULTS.md.

    ``markdown`` is the body of the section (tables, notes); the heading and the
    machine/date/command stamp are added here.
    """
    meta = stamp()
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    out = RESULTS_DIR / f"{name}.json"
    tmp = out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps({"meta": meta, **results}, indent=2, default=_jsonable) + "\n")
    tmp.replace(out)

    m = meta["machine"]
    section = (
        f"<!-- begin {name} -->\n## {name}\n\n"
        f"Machine: {m['cpu']}, {m['cores']} cores, {m['memory_gb']} GB, Python {m['python']}. "
        f"Date: {meta['date']}. Command: `{meta['command']}`\n\n"
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


# --- a script's sections: --only, --list, and results merged into the previous run's ------------------------
@dataclass
class Section:
    """One part of a benchmark script: ``run(args)`` measures it and returns the results' top-level entries it
    owns (``keys``)."""

    name: str
    run: Callable[[argparse.Namespace], dict[str, Any]]
    help: str
    keys: tuple[str, ...]


@dataclass
class Part:
    """A part of a benchmark script with a results file and RESULTS.md section of its own: ``bench(args)`` measures
    it and returns (its results, its markdown), published whole under ``results(args)`` when it ends (nothing of an
    earlier run is kept: the file is this part's). ``check(results)``: whether what it measured passed (a part that
    tests a promise of the service); the script then exits 1 when one did not."""

    name: str
    bench: Callable[[argparse.Namespace], tuple[dict[str, Any], str]]
    help: str
    results: Callable[[argparse.Namespace], str]
    check: Callable[[dict[str, Any]], bool] | None = None


class Sections:
    """The sections of one results name (``results/<name>.json``, the ``<name>`` section of RESULTS.md) and the
    script's command line: ``--only NAME[,NAME]`` runs those sections and keeps every other one from the previous
    results file, ``--list`` prints them; without ``--only`` all run, in the order declared. ::

        sections = Sections("sweep", __doc__)
        sections.parser.add_argument("--quick", ...)           # the script's own options

        @sections.section("speed", "the fused kernel against the reference", keys=("speed",))
        def speed(args): return {"speed": ...}

        raise SystemExit(sections.main(markdown))                # markdown(results, kept) -> the section body

    The results file also holds ``runs``: per section the date, command and load averages of the run that
    measured it; RESULTS.md gets a line naming the sections kept from earlier runs and one on the load of this
    run (:func:`benchmarks._timing.load_note`). Results are published after every section, so a long run
    stopped half-way keeps what it measured. ``upgrade(previous)`` may convert a results file written before
    the script had sections (its ``runs`` guessed from what it recorded).

    A script whose parts each write their own results (``results/<part's name>.json``, their own RESULTS.md section)
    declares them with :meth:`part` instead; ``--only`` and ``--list`` name them the same way, and ``main`` needs no
    ``markdown`` when the script has nothing else.
    """

    def __init__(self, name: str, doc: str | None, *, upgrade: Callable[[dict], dict] | None = None):
        self.name = name
        self.sections: dict[str, Section | Part] = {}
        self.upgrade = upgrade
        self.parser = argparse.ArgumentParser(
            prog=prog(),
            description=(doc or name).strip().split("\n\n")[0],
            epilog=f"Results: benchmarks/results/{name}.json and the {name} section of benchmarks/RESULTS.md; "
                   "--list names the sections.")
        self.parser.add_argument("--only", metavar="NAME[,NAME]",
                                 help="run only these sections; keep the others of the previous results (--list)")
        self.parser.add_argument("--list", action="store_true", help="list the sections and exit")
        self.parser.add_argument("--settle", type=float, default=None, metavar="SECONDS",
                                 help="wait up to this long for the 1-minute load average to fall under 0.5 before "
                                      "measuring (default 180; 0: do not wait)")

    def section(self, name: str, help: str, keys: tuple[str, ...] | None = None):
        """Declare a section (a decorator): ``fn(args) -> {key: value}`` for the ``keys`` it owns (default
        ``(name,)``)."""
        def register(fn: Callable[[argparse.Namespace], dict[str, Any]]):
            self.sections[name] = Section(name, fn, help, keys or (name,))
            return fn
        return register

    def add(self, name: str, help: str, bench: Callable[[argparse.Namespace], tuple[dict[str, Any], str]]) -> None:
        """Declare a section whose ``bench(args)`` returns (its results, its markdown): the markdown is kept in
        the results (``markdown``, so a later ``--only`` run shows a kept section's tables again) beside the
        section's 1-minute load averages (``load_average_start_end``); :meth:`stored_markdown` joins them."""
        def run(args: argparse.Namespace) -> dict[str, Any]:
            load0 = os.getloadavg()[0]
            out, md = bench(args)
            out.update(load_average_start_end=[round(load0, 2), round(os.getloadavg()[0], 2)], markdown=md)
            print(md, file=sys.stderr)
            return {name: out}
        self.section(name, help)(run)

    def part(self, name: str, help: str, bench: Callable[[argparse.Namespace], tuple[dict[str, Any], str]],
             results: str | Callable[[argparse.Namespace], str] | None = None,
             check: Callable[[dict[str, Any]], bool] | None = None) -> None:
        """Declare a :class:`Part`: ``bench(args)`` returns (its results, its markdown), published under
        ``results`` (a name, or a function of the command line that names it; default ``<script's name>_<name>``);
        ``check`` as :class:`Part` says."""
        named = results if callable(results) else (lambda _args, n=results or f"{self.name}_{name}": n)
        self.sections[name] = Part(name, bench, help, named, check)

    def _merged(self) -> list[Section]:
        """The sections whose results merge into the script's own results file (every one but the parts)."""
        return [s for s in self.sections.values() if isinstance(s, Section)]

    def stored_markdown(self, results: dict[str, Any], kept: list[str]) -> list[str]:
        """The markdown of every section :meth:`add` declared that ``results`` holds, in order, those in
        ``kept`` marked as from an earlier run (a :meth:`section`'s results carry no markdown: the script's own
        ``markdown`` renders them)."""
        return [results[k]["markdown"] + ("\n(from an earlier run)\n" if k in kept else "")
                for k in (s.name for s in self._merged())
                if isinstance(results.get(k), dict) and "markdown" in results[k]]

    def previous(self) -> dict[str, Any]:
        """The results file as it is now (``{}`` without one), upgraded to sections."""
        path = RESULTS_DIR / f"{self.name}.json"
        if not path.exists():
            return {}
        old = json.loads(path.read_text())
        if "runs" not in old and self.upgrade is not None:
            old = self.upgrade(old)
        return old

    def main(self, markdown: Callable[[dict[str, Any], list[str]], str] | None = None, argv: list[str] | None = None,
             *, extra: Callable[[argparse.Namespace], dict[str, Any]] | None = None) -> int:
        """Parse the command line and run the chosen sections (see the class). ``markdown(results, kept)``: the
        body of the script's own RESULTS.md section (needed when it has sections that are not parts);
        ``extra(args)``: top-level entries of every run that belong to no section."""
        from benchmarks._timing import SETTLE_LOAD_S, load_average, load_note, settle_load

        args = self.parser.parse_args(argv)
        if args.list:
            width = max(map(len, self.sections))
            for s in self.sections.values():
                print(f"{s.name:<{width}}  {s.help}")
            return 0
        chosen = [n.strip() for n in args.only.split(",") if n.strip()] if args.only else list(self.sections)
        unknown = [n for n in chosen if n not in self.sections]
        if unknown or not chosen:
            self.parser.error(f"unknown section(s): {', '.join(unknown) or '(none)'}; "
                              f"the sections: {', '.join(self.sections)}")
        previous = self.previous()
        runs = dict(previous.get("runs", {}))
        if "meta" in previous:  # a file from before sections: its last run measured what its --only named
            meta = previous["meta"]
            named = re.search(r"--only[= ](\S+)", meta["command"])
            for n in (s.name for s in self._merged()):
                if n not in runs and any(k in previous for k in self.sections[n].keys):
                    runs[n] = ({"date": meta["date"], "command": meta["command"]}
                               if not named or n in named[1].split(",")
                               else {"date": f"{meta['date']} or earlier", "command": None})
        results = {k: previous[k] for s in self._merged() for k in s.keys if k in previous}
        results.update(extra(args) if extra else {})
        start = settle_load(SETTLE_LOAD_S if args.settle is None else args.settle)
        done: list[str] = []
        failed: list[str] = []
        for n in chosen:
            print(f"[{self.name}] {n} ...", file=sys.stderr, flush=True)
            section = self.sections[n]
            if isinstance(section, Part):
                out, md = section.bench(args)
                publish(section.results(args), out, md)
                if section.check is not None and not section.check(out):
                    failed.append(n)
                continue
            load0 = load_average()
            new = section.run(args)
            for k in self.sections[n].keys:
                results.pop(k, None)
            results.update(new)
            now = stamp()
            runs[n] = {"date": now["date"], "command": now["command"], "load_average": [load0, load_average()]}
            done.append(n)
            kept = [k for k in (s.name for s in self._merged()) if k in runs and k not in done]
            if markdown is None:
                raise TypeError(f"{self.name}: sections that are not parts need main(markdown)")
            body = markdown(results, kept).rstrip()
            notes = [f"{k}: from the run of {runs[k]['date']}"
                     + (f" (`{runs[k]['command']}`)" if runs[k].get("command") else "") + ", kept unchanged." for k in kept]
            notes.append(f"Measured in this run: {', '.join(done)}. " + load_note(start, load_average()))
            body += "\n\n" + "\n".join(f"- {line}" for line in notes) + "\n"
            publish(self.name, {**results, "runs": runs, "load_at_start": start}, body)
        if failed:
            print(f"[{self.name}] what {', '.join(failed)} measured did not pass its check", file=sys.stderr)
        return 1 if failed else 0
