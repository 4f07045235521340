"""Reader threads against reader processes (``benchmarks/live_ingest.py``, section ``readers``; issue 55: "one reader
per camera, thread or process: measure").

The rig's RTSP cameras run in a process of their own (:mod:`benchmarks._camera_process`); each design runs in a
fresh process of its own (:mod:`benchmarks._readers_trial`), in turn (thread, process, thread-bgr, thread, ...) so
that all see the same load, and is measured over the same window: frames delivered per camera, sets per second, CPU
(the reader side's process and its reader processes), the age of the newest frames when the assembler takes a set,
and peak resident memory.
"""
from __future__ import annotations

import contextlib
import json
import pickle
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Iterator

from benchmarks._report import md_table
from benchmarks._reader_process import REPOSITORY
from benchmarks._readers_trial import DESIGNS

ROUNDS = 2
AGE_MARGIN_MS = 5.0
"""Newest-frame ages (p95, ms) this close count as the same: the two rounds of one design differ by about as much."""
TRIAL_SLACK_S = 120.0
"""Seconds a trial may take beyond its window (starting ten readers, the first set, the warm-up, stopping)."""


@contextlib.contextmanager
def camera_process(rig: Any, streams: list[list[bytes]], fps: float) -> Iterator[str]:
    """The rig's cameras (per camera its H.264 access units, looped at ``fps``) served from a process of their own;
    yields the server's base URL (``rtsp://127.0.0.1:PORT``)."""
    first = rig.cameras[0]
    spec = {"names": [c.name for c in rig.cameras], "width": first.width, "height": first.height, "fps": fps,
            "access_units": streams}
    with tempfile.TemporaryDirectory(prefix="sweepcast-bench-readers-") as folder:
        path = Path(folder) / "cameras.pickle"
        path.write_bytes(pickle.dumps(spec))
        server = subprocess.Popen([sys.executable, "-m", "benchmarks._camera_process", str(path)],
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=REPOSITORY)
        try:
            base = server.stdout.readline().strip()
            if not base.startswith("rtsp://"):
                raise SystemExit(f"the camera process did not start (it said {base!r})")
            yield base
        finally:
            server.stdin.close()
            try:
                server.wait(15)
            except subprocess.TimeoutExpired:
                server.kill()
                server.wait()


def measure(rig: Any, streams: list[list[bytes]], fps: float, seconds: float) -> dict[str, Any]:
    """ROUNDS rounds of each design in turn, each trial over ``seconds``: ``{"readers": {"seconds", "trials": [...]}}``
    with each trial's measurements (:func:`benchmarks._readers_trial.trial`) and its round."""
    first = rig.cameras[0]
    trials = []
    with camera_process(rig, streams, fps) as base:
        urls = [f"{base}/{c.name}" for c in rig.cameras]
        for round_ in range(1, ROUNDS + 1):
            for design in DESIGNS:
                print(f"[readers] round {round_}: {design} readers ...", file=sys.stderr, flush=True)
                done = subprocess.run([sys.executable, "-m", "benchmarks._readers_trial", design, str(seconds),
                                       str(fps), str(first.width), str(first.height), *urls],
                                      stdout=subprocess.PIPE, text=True, timeout=seconds + TRIAL_SLACK_S,
                                      cwd=REPOSITORY)
                if done.returncode:
                    raise SystemExit(f"the {design} trial failed (exit {done.returncode}); its messages are above")
                trials.append({**json.loads(done.stdout.strip().splitlines()[-1]), "round": round_})
                print(f"[readers] {trials[-1]}", file=sys.stderr, flush=True)
    bytes_per_frame = statistics.mean(len(unit) for stream in streams for unit in stream)
    return {"readers": {"seconds": seconds, "rounds": ROUNDS, "bytes_per_frame": bytes_per_frame, "trials": trials}}


def mean_of(trials: list[dict[str, Any]], design: str) -> dict[str, float]:
    """Each numeric measurement of ``design``'s trials, averaged over its rounds (per-camera lists: their minimum
    and mean)."""
    mine = [t for t in trials if t["design"] == design]
    keys = [k for k, v in mine[0].items() if isinstance(v, (int, float)) and not isinstance(v, bool) and k != "round"]
    out = {k: statistics.mean(t[k] for t in mine) for k in keys if all(t[k] is not None for t in mine)}
    out["fps_per_camera_min"] = min(min(t["fps_per_camera"]) for t in mine)
    out["child_peak_rss_mb_each"] = statistics.mean(statistics.mean(t["child_peak_rss_mb"]) if t["child_peak_rss_mb"]
                                                    else 0.0 for t in mine)
    return out


DESIGN_NAMES = {"thread": "reader threads (sweepcast live)", "process": "reader processes",
                "thread-bgr": "reader threads, BGR in the reader"}


def summary(trials: list[dict[str, Any]]) -> str:
    """Each design's means over its rounds, one row each."""
    rows = []
    for design in DESIGNS:
        m = mean_of(trials, design)
        rows.append([DESIGN_NAMES[design], m["frames_per_s"], m["fps_per_camera_min"], m["sets_per_s"], m["cores"],
                     m["newest_age_p50_ms"], m["newest_age_p95_ms"], m["set_age_p95_ms"],
                     m["parent_peak_rss_mb"] + m["children_peak_rss_mb"]])
    return md_table(["design", "frames/s all", "per camera (min)", "sets/s", "cores", "newest frame age p50 ms",
                     "p95 ms", "set age p95 ms", "peak RSS MB (parent + reader processes)"], rows)


def verdict(trials: list[dict[str, Any]]) -> str:
    """The comparison in words, from the rounds' means."""
    thread, process, early = (mean_of(trials, d) for d in ("thread", "process", "thread-bgr"))
    memory = process["parent_peak_rss_mb"] + process["children_peak_rss_mb"]
    younger = thread["newest_age_p95_ms"] - process["newest_age_p95_ms"]
    return (f"Reader processes cost {process['cores'] / thread['cores']:.2f} times the CPU of reader threads "
            f"({process['cores']:.2f} against {thread['cores']:.2f} cores for {process['frames_per_s']:.0f} and "
            f"{thread['frames_per_s']:.0f} frames/s) and {memory / thread['parent_peak_rss_mb']:.1f} times the "
            f"memory ({memory:.0f} MB, {process['child_peak_rss_mb_each']:.0f} MB per reader process, against "
            f"{thread['parent_peak_rss_mb']:.0f} MB). Their newest frame is {abs(younger):.0f} ms "
            f"{'younger' if younger >= 0 else 'older'} at p95 "
            f"({process['newest_age_p95_ms']:.0f} against {thread['newest_age_p95_ms']:.0f} ms); reader threads "
            f"that convert each frame to BGR as they decode it, as a reader process must, are at "
            f"{early['newest_age_p95_ms']:.0f} ms for {early['cores']:.2f} cores and "
            f"{early['parent_peak_rss_mb']:.0f} MB. " + conclusion(thread, process, early))


def conclusion(thread: dict[str, float], process: dict[str, float], early: dict[str, float]) -> str:
    """Which design the means favour, in one sentence."""
    dearer = process["cores"] > thread["cores"] and process["parent_peak_rss_mb"] + process["children_peak_rss_mb"] \
        > thread["parent_peak_rss_mb"]
    if not dearer:
        return "Processes were not dearer in this run: the choice of threads is open again (see the table)."
    if early["newest_age_p95_ms"] <= process["newest_age_p95_ms"] + AGE_MARGIN_MS:
        return ("So reader threads stay: processes cost more for nothing threads cannot have (converting each frame "
                "as it is decoded).")
    return "Reader threads stay on CPU and memory; processes deliver younger frames than threads can."


def markdown(result: dict[str, Any]) -> list[str]:
    """The section's lines of RESULTS.md."""
    trials = result["trials"]
    size = trials[0]["size"]
    md = ["", "### Reader threads or reader processes", "",
          f"{trials[0]['cameras']} RTSP cameras {size} H.264 at {trials[0]['fps']:g} fps "
          f"({result['bytes_per_frame'] / 1e3:.1f} KB per frame, the cameras of the ingest section served from a "
          "process of their own) read by (a) one reader thread per camera, as `sweepcast live` runs them (a frame is "
          "converted to BGR when a set takes it), (b) one reader process per camera (`benchmarks/_reader_process.py`: "
          "the same reader in a child process, which converts each frame to BGR into a ring of 8 frame slots in "
          "shared memory and sends the slot's number down a pipe; a thread in the parent copies it out into the "
          "camera's mailbox), and (c) reader threads that convert each frame to BGR as they decode it, as the "
          "processes must. The same set assembler takes sets from the mailboxes in all three and takes their pixels "
          "as BGR (no JPEG encoding: the same for all). Each design in a fresh process, in turn "
          f"({', '.join(DESIGNS)}, {result['rounds']} rounds), {result['seconds']:g} s each after a 3 s warm-up. "
          "CPU: the reader side's process and its reader processes (not the cameras); age: when a set's pixels "
          "have been taken, now minus the capture instant (the camera's clock) of each camera's newest frame, and of "
          "the set's instant; peak RSS: VmHWM. Machine busy: all cores' busy time during the window (everything "
          "running on the machine, in cores).", "",
          md_table(["round", "design", "frames/s per camera (min)", "frames/s all", "sets/s", "cores: all",
                    "parent", "reader processes", "newest frame age p50 ms", "p95 ms", "set age p50 ms", "p95 ms",
                    "parent peak RSS MB", "reader processes' peak RSS MB (sum)", "machine busy cores", "load 1 min"],
                   [[t["round"], t["design"], min(t["fps_per_camera"]), t["frames_per_s"], t["sets_per_s"],
                     t["cores"], t["parent_cores"], t["children_cores"], t["newest_age_p50_ms"],
                     t["newest_age_p95_ms"], t["set_age_p50_ms"], t["set_age_p95_ms"], t["parent_peak_rss_mb"],
                     t["children_peak_rss_mb"], t["machine_busy_cores"], t["load_average_start_end"][0]]
                    for t in trials]),
          "", "Means of the rounds:", "", summary(trials)]
    torn = sum(t["torn"] for t in trials)
    if torn:
        md.append(f"\n{torn} frames were overwritten in shared memory before the parent copied them (not delivered).")
    md += ["", "**Verdict**: " + verdict(trials)]
    return md
