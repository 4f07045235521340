"""A survey's sparse model, stage by stage: plan (:mod:`.plan`), tracks per block, matches across flight lines,
submodels (the lens calibrated on the first, then held by the others), merge (:mod:`.merge`); each stage's work
as tasks (:mod:`.sparse`) through the job's :class:`~.stages.Stages`."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from workers.common.jobctx import JobInputError
from workers.workarea import InputRef

from ..calibration import Intrinsics
from ..flightmeta import FlightMeta
from ..geo import to_projected
from ..georef import Georeference, survey_epsg, survey_origin
from ..params import ReconstructionParams
from ..reconstruction import SparseModel
from ..selfcal import FocalPrior
from .merge import merge
from .photos import PhotoSource
from .plan import PAIRS_PER_TASK, SurveyPlan, plan_survey, reference_order
from .sparse import (BlockItem, PairsItem, SparseJob, SubmodelItem, block_name, load_submodel, map_submodel,
                     match_pairs, pairs_name, submodel_name, track_block)
from .stages import Stages

class SurveyUnplaced(Exception):
    """Every submodel was mapped, but no submodel's GPS positions could place it (too few, all at one spot): the
    photos are no survey; the message says why."""


# Shares of the sparse part's progress (0..1 of it) each stage ends at.
_TRACK, _MATCH, _MAP, _MERGE = 0.4, 0.55, 0.95, 1.0


@dataclass
class SurveySparse:
    """What the sparse stages made: the model (in the survey's UTM frame), its georeference, the plan, each photo's
    sharpness (position -> Laplacian variance), the stages' report items, and the photos that failed."""

    model: SparseModel
    georef: Georeference
    plan: SurveyPlan
    sharpness: dict[int, float]
    report: dict[str, Any]


def is_survey(meta: FlightMeta, params: ReconstructionParams) -> bool:
    """Whether a job runs as a survey: stills with GPS positions (and georeferencing not off)."""
    return meta.kind == "images" and meta.gps_source is not None and params.georeference != "off"


def survey_sparse(stages: Stages, media: InputRef, meta: FlightMeta, intrinsics: Intrinsics, prior: FocalPrior | None,
                  source: str, params: ReconstructionParams, span: tuple[float, float]) -> SurveySparse:
    """The sparse model of a survey (module docstring); progress from ``span[0]`` to ``span[1]``. Raises
    JobInputError when no submodel can be mapped (the reference's reason), :class:`SurveyUnplaced` when none can be
    placed by its GPS."""
    names = list(meta.photos)
    gps = meta.positions_by_name()
    epsg = survey_epsg(list(gps.values()))
    known = [n for n in names if n in gps]
    xyz = np.full((len(names), 3), np.nan)
    xyz[[names.index(n) for n in known]] = to_projected([gps[n] for n in known], epsg)
    origin = survey_origin(xyz[np.isfinite(xyz[:, 0])])
    plan = stages.once("plan", lambda: plan_survey(xyz[:, :2] - origin[:2], params.submodel_photos,
                                                  params.submodel_overlap_m), _at(span, 0.0))
    w, h = meta.size
    scale = min(1.0, params.max_width / w)
    working = (int(round(w * scale)), int(round(h * scale)))
    job = SparseJob(stages.work, PhotoSource(media, working, (w, h)), params, tuple(names), (w, h), scale, intrinsics,
                    intrinsics.dist is not None)

    blocks = stages.map("track", track_block, [BlockItem(job, b, tuple(int(i) for i in ph)) for b, ph in
                                               enumerate(plan.blocks)], (_at(span, 0.0), _at(span, _TRACK)),
                        finished=lambda it: stages.found(block_name(it.block)), unit="photos",
                        count=lambda it: len(it.photos))
    failed = {int(k): v for m in blocks for k, v in m["failed"].items()}
    bad = np.zeros(len(names), bool)
    bad[list(failed)] = True
    pairs = [tuple(int(v) for v in pr) for pr in plan.pairs if not bad[pr[0]] and not bad[pr[1]]]
    chunks = [tuple(pairs[k:k + PAIRS_PER_TASK]) for k in range(0, len(pairs), PAIRS_PER_TASK)]
    matched = stages.map("match", match_pairs, [PairsItem(job, c, ch) for c, ch in enumerate(chunks)],
                         (_at(span, _TRACK), _at(span, _MATCH)), finished=lambda it: stages.found(pairs_name(it.chunk)),
                         unit="pairs", count=lambda it: len(it.pairs))
    chunk_photos = [np.unique(np.asarray(ch, np.int64)) for ch in chunks]
    flow = [tuple(r) for m in blocks for r in m["flow_pairs"]]
    seconds = (sum(m["seconds_decode"] for m in blocks), sum(m["seconds_track"] for m in blocks))
    block_of = plan.block_of()

    def item(s: int, lens) -> SubmodelItem:
        members = np.setdiff1d(plan.submodels[s].members, np.flatnonzero(bad))
        inside = np.zeros(len(names), bool)
        inside[members] = True
        return SubmodelItem(
            job, s, tuple(int(m) for m in members), tuple(int(b) for b in np.unique(block_of[members])),
            tuple(c for c, ph in enumerate(chunk_photos) if inside[ph].sum() >= 2),
            tuple(r for r in flow if inside[r[0]] and inside[r[1]]), seconds, lens,
            prior if lens is None else None, gps, meta.gps_source, meta.altitude, epsg, tuple(origin))

    subs = _map_submodels(stages, plan, item, prior is not None, (_at(span, _MATCH), _at(span, _MAP)))
    mapped = {s: m for s, m in subs.items() if "failed" not in m}
    if not mapped:
        first = subs[reference_order(plan.submodels)[0]]
        if all(m.get("unplaced") for m in subs.values()):
            raise SurveyUnplaced(first["failed"])
        raise JobInputError(first["failed"])
    reference = next(s for s in reference_order(plan.submodels) if s in mapped)

    def merged() -> tuple[SparseModel, Georeference, dict[str, Any]]:
        models = {s: load_submodel(stages.work, s) for s in mapped}
        if len(plan.submodels) == 1:
            model, ref = models[reference]
            return model, ref, {}
        centres = np.array([sub.centre for sub in plan.submodels])
        return merge(models, plan.owner(), centres, reference)

    model, georef, aligned = stages.once("merge", merged, _at(span, _MAP))
    warnings = [f"{names[k]}: {v}" for k, v in sorted(failed.items())]
    warnings += [f"submodel {s} ({m['photos']} photos) could not be mapped: {m['failed']}; its photos come from the "
                 "submodels around it where they overlap" for s, m in subs.items() if "failed" in m]
    model.report.setdefault("warnings", []).extend(warnings)
    model.report["intrinsics"]["source"] = source
    sharp = {int(k): float(v) for m in blocks for k, v in m["sharpness"].items()}
    report = {"plan": plan.report(), "submodels": [subs[s] for s in sorted(subs)],
              "cross_line_pairs": {"pairs": len(pairs), "matched": sum(m["matched"] for m in matched),
                                   "inlier_matches": sum(m["inliers"] for m in matched)},
              "photos_failed": len(failed)}
    if aligned:
        report["alignment"] = aligned
    return SurveySparse(model, georef, plan, sharp, report)


def _map_submodels(stages: Stages, plan: SurveyPlan, item, calibrate: bool, span: tuple[float, float]
                   ) -> dict[int, dict[str, Any]]:
    """Map every submodel: with self-calibration the reference first (trying the next when one cannot be mapped),
    its lens then held by the others, all at once; with given intrinsics all at once."""
    order = reference_order(plan.submodels)
    n = len(order)
    results: dict[int, dict[str, Any]] = {}
    lens = None
    if calibrate:
        for s in order:
            results[s] = stages.map("submodel lens", map_submodel, [item(s, None)], (span[0], span[0]),
                                    finished=lambda it: stages.found(submodel_name(it.index)),
                                    unit=f"(calibrating the lens on {len(plan.submodels[s].members)} photos)")[0]
            if "failed" not in results[s]:
                lens = load_submodel(stages.work, s)[0].lens
                break
        if lens is None:
            return results
    rest = [s for s in order if s not in results]
    mid = span[0] + (span[1] - span[0]) * (n - len(rest)) / max(n, 1)
    metas = stages.map("submodels", map_submodel, [item(s, lens) for s in rest], (mid, span[1]),
                       finished=lambda it: stages.found(submodel_name(it.index)), unit="submodels")
    results.update(zip(rest, metas))
    return results


def _at(span: tuple[float, float], share: float) -> float:
    return span[0] + (span[1] - span[0]) * share
