"""The sweep benchmark's command line (:mod:`benchmarks.sweep`): ``python -m benchmarks.sweep --help``."""
from __future__ import annotations

import numba

from benchmarks._report import Sections
from benchmarks.sweep import __doc__ as DOC
from benchmarks.sweep import speed, stereo, viewer, weighting


def upgrade(old: dict) -> dict:
    """A results file of the script before sections (--weighting-only / --stereo-only / --speed-only, each
    keeping the others' tables with the run they came from): each section's run, from what it recorded."""
    meta = old.get("meta")
    if not meta:
        return old
    here = {"date": meta["date"], "command": meta["command"]}
    quality = {k: old.get("quality_from_run", meta)[k] for k in ("date", "command")}
    others = {k: old.get("speed_and_stereo_from_run", meta)[k] for k in ("date", "command")}
    stereo_run = {"date": f"{meta['date']} or earlier", "command": "python benchmarks/sweep.py --stereo-only"}
    cmd = meta["command"]
    if "--speed-only" in cmd:
        runs = {"weighting": quality, "stereo": stereo_run, "speed": here}
    elif "--stereo-only" in cmd:
        runs = {"weighting": quality, "stereo": here, "speed": quality}
    elif "--weighting-only" in cmd:
        runs = {"weighting": here, "stereo": others, "speed": others}
    else:
        runs = {"weighting": here, "stereo": here, "speed": here}
    return {**old, "runs": {k: v for k, v in runs.items() if k != "stereo" or old.get("stereo")}}


sections = Sections("sweep", DOC, upgrade=upgrade)
sections.parser.add_argument("--quick", action="store_true", help="a short run (fewer views, frames and configurations)")
sections.parser.add_argument("--skip-data", action="store_true", help="weighting: skip the Middlebury and temple sets")


@sections.section("weighting", "quality and seams of every colour weighting: procedural, Middlebury, temple, moving "
                               "cameras, the dome rig and its picture (issue 22)",
                  keys=("quality", "temporal", "dome", "weighting_notes"))
def _weighting(args) -> dict:
    return weighting.run(args.quick, args.skip_data)


@sections.section("stereo", "the sweep's aggregations against SGBM + DIBR on Middlebury, and their live speed "
                            "(issue 20)")
def _stereo(args) -> dict:
    return {"stereo": stereo.stereo(args.quick)}


@sections.section("speed", "the fused kernel against the per-plane reference; the live configuration",
                  keys=("speed", "speed_threads"))
def _speed(args) -> dict:
    return {"speed": speed.speed(args.quick), "speed_threads": numba.get_num_threads()}


sections.add("viewer", "the viewer's quality levels beside every option: PSNR on Middlebury, temple, the studio and a "
                       "textureless occluder, smears at occluding edges, flicker, live speed (issue 58)",
             lambda args: viewer.run(args.quick))


def markdown(results: dict, kept: list[str]) -> str:
    """The body of the sweep section: the tables of whatever ``results`` holds, then the notes."""
    parts = weighting.markdown_parts(results) + speed.markdown_parts(results)
    if results.get("stereo"):
        parts.append(stereo.stereo_markdown(results["stereo"]))
    parts += sections.stored_markdown(results, kept)
    notes = list(results.get("weighting_notes") or weighting.quality_notes() + weighting.MIDDLEBURY_NOTES)
    if results.get("speed"):
        threads = results.get("speed_threads", "its")
        notes.append(f"The sweep runs on {threads} threads and the reference mostly on one; the CPU-time speedup is "
                     "the work ratio, nearly independent of the load; the renderer and the reference were measured "
                     "in the same run, interleaved.")
    parts.append("\n".join(f"- {n}" for n in notes))
    return "\n\n".join(parts)


if __name__ == "__main__":
    raise SystemExit(sections.main(markdown))
