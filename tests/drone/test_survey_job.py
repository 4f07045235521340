"""A survey through the job: split into submodels and merged, every photo in the map, the work in tiles, a
limit that refuses with the cell size that would fit, a job that resumes from the stages it finished, and the
work spread over a two-node Ray cluster through the service."""
from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio

from harness.scenarios import run_scenario
from harness.surveys import EPSG, ORIGIN, small_survey, zipped
from tests.fakectx import FakeContext
from workers.common.jobctx import JobInputError
from workers.drone.frames import open_media, select_frames
from workers.drone.calibration import from_values
from workers.drone.job import run_reconstruction
from workers.drone.params import ReconstructionParams
from workers.drone.pipeline import run_pipeline
from workers.drone.survey import ground, map_stages
from workers.synth.survey import true_orthophoto

FAST = {"max_features": 600, "dense_planes": 32}


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    folder = tmp_path_factory.mktemp("survey") / "stills"
    scene, cams, frames, paths = small_survey(folder)
    return scene, cams, folder, zipped(paths)


def test_a_split_survey_killed_in_its_last_stage_resumes_and_gives_one_map(tmp_path, survey, monkeypatch):
    scene, cams, _, data = survey
    ctx = FakeContext(tmp_path, {**FAST, "submodel_photos": 4}, {"media": data})
    monkeypatch.setattr(ground, "MAX_ORTHO_TILE", ground.MIN_DSM_TILE)  # tiles as small as allowed: one of them dies
    real_ortho = map_stages.ortho_tile
    calls = {"ortho": 0, "depth": 0}

    def dies_on_the_second_tile(item):
        calls["ortho"] += 1
        if calls["ortho"] == 2:
            raise RuntimeError("the worker was lost")
        return real_ortho(item)

    monkeypatch.setattr(map_stages, "ortho_tile", dies_on_the_second_tile)
    with pytest.raises(RuntimeError, match="worker was lost"):
        run_reconstruction(ctx)
    assert not ctx.result_path("report.json").exists()
    real_depth = map_stages.depth_maps

    def counted_depth(item):
        calls["depth"] += 1
        return real_depth(item)

    monkeypatch.setattr(map_stages, "ortho_tile", real_ortho)
    monkeypatch.setattr(map_stages, "depth_maps", counted_depth)
    summary = run_reconstruction(ctx)  # the next attempt, the same job's work area
    assert calls["depth"] == 0  # no depth map made twice
    report = json.loads(ctx.result_path("report.json").read_text())
    stages = report["stages"]["stages"]
    assert report["stages"]["resumed_from_earlier_attempt"]
    assert stages["dense depth"]["resumed"] == stages["dense depth"]["items"] == len(cams)
    assert stages["orthophoto"]["resumed"] == 1 and stages["orthophoto"]["items"] > 1
    assert stages["merge"]["resumed"] == 1 and stages["submodels"]["resumed"] == stages["submodels"]["items"]
    # every photo in one map, from two submodels aligned on the photos they share
    assert summary["frames_registered"] == len(cams) and report["survey"]["plan"]["submodels"] == 2
    alignment = report["survey"]["alignment"]
    assert alignment["shared_photos"] >= 3 and alignment["after"]["centre_rmse_m"] < 0.1
    assert report["georeference"]["camera_position_error_m"]["rmse"] < 0.5
    cov = summary["coverage"]
    assert cov["dsm"] > 0.99 and cov["orthophoto"] > 0.99
    progress = [s for _, s in ctx.progress_calls]
    assert f"track {len(cams)}/{len(cams)} photos" in progress and "dense depth 8/8 (8 done before)" in progress
    assert not (tmp_path / "store" / "work").exists()  # the work area is gone once the results are written
    with rasterio.open(ctx.result_path("orthophoto.tif")) as src:
        rgba = np.moveaxis(src.read(), 0, 2)
        x0, y0, gsd = src.transform.c - ORIGIN[0], src.transform.f - ORIGIN[1], src.transform.a
        assert src.crs.to_epsg() == EPSG
    truth, _ = true_orthophoto(scene, x0, y0, gsd, rgba.shape[1], rgba.shape[0], supersample=1)
    seen = rgba[..., 3] > 0
    mse = np.mean((rgba[..., :3][seen].astype(float) - truth[..., ::-1][seen]) ** 2)
    assert 10 * np.log10(255**2 / mse) > 20.0  # in the right place: a metre's shift costs more than 8 dB here


def test_tiles_join_without_seams(survey, monkeypatch):
    """The same survey in tiles of 64 cells and in one tile: the same cloud, DSM and orthophoto."""
    _, _, folder, _ = survey
    params = ReconstructionParams(**FAST)
    monkeypatch.setattr(ground, "MIN_DSM_TILE", 4096)
    monkeypatch.setattr(ground, "MAX_ORTHO_TILE", 4096)
    one = run_pipeline(folder, params)
    monkeypatch.setattr(ground, "MIN_DSM_TILE", 64)
    monkeypatch.setattr(ground, "MAX_ORTHO_TILE", 64)
    many = run_pipeline(folder, params)
    try:
        assert len(one.maps.tiles) == 1 and len(many.maps.tiles) > 16
        assert abs(many.dense.points - one.dense.points) < 0.01 * one.dense.points
        d1, d2 = one.maps.dsm(), many.maps.dsm()
        both = np.isfinite(d1) & np.isfinite(d2)
        assert both.mean() > 0.9 and np.median(np.abs(d1 - d2)[both]) < 0.01
        o1, o2 = one.maps.orthophoto(), many.maps.orthophoto()
        lit = (o1[..., 3] > 0) & (o2[..., 3] > 0)
        mse = np.mean((o1[..., :3][lit].astype(float) - o2[..., :3][lit]) ** 2)
        assert 10 * np.log10(255**2 / max(mse, 1e-9)) > 30.0
    finally:
        one.discard_work()
        many.discard_work()


def test_a_map_beyond_the_limit_is_refused_before_the_dense_pass_saying_what_would_fit(tmp_path, survey, monkeypatch):
    _, _, _, data = survey
    monkeypatch.setenv("SWEEPCAST_MAX_MAP_PIXELS", "1000000")
    ctx = FakeContext(tmp_path, {**FAST, "gsd_cm": 1}, {"media": data})
    with pytest.raises(JobInputError, match=r"SWEEPCAST_MAX_MAP_PIXELS\): ask for gsd_cm [\d.]+ or more"):
        run_reconstruction(ctx)
    assert not any("dense depth" in s for _, s in ctx.progress_calls)


def test_photos_whose_gps_cannot_place_them_run_as_one_sequence_in_their_own_frame(tmp_path, survey):
    """GPS that places nothing (every photo at one spot, as a logger stuck on its first fix): with georeference
    'auto' the photos are reconstructed all the same, in their own frame, and the report says why."""
    import piexif

    _, cams, folder, _ = survey
    stuck = sorted(folder.glob("*.jpg"))
    first = piexif.load(str(stuck[0]))["GPS"]
    paths = []
    for p in stuck:
        exif = piexif.load(str(p))
        exif["GPS"] = first
        target = tmp_path / p.name
        target.write_bytes(p.read_bytes())
        piexif.insert(piexif.dump(exif), str(target))
        paths.append(target)
    ctx = FakeContext(tmp_path / "job", {**FAST, "dense": False, "orthophoto": False, "dsm": False},
                      {"media": zipped(paths)})
    summary = run_reconstruction(ctx)
    report = json.loads(ctx.result_path("report.json").read_text())
    assert not summary["georeferenced"] and summary["frames_registered"] == len(cams)
    assert "survey" not in report and any("not georeferenced" in w for w in report["warnings"])
    ctx = FakeContext(tmp_path / "required", {**FAST, "georeference": "required"}, {"media": zipped(paths)})
    with pytest.raises(JobInputError, match="georeference: .*within 2 m"):
        run_reconstruction(ctx)


def test_stills_are_never_thinned_by_max_frames(survey):
    _, cams, folder, _ = survey
    source = open_media(folder)
    frames = list(select_frames(source, from_values(300.0, 300.0, 159.5, 119.5), frame_step=1, max_frames=3))
    assert len(frames) == len(cams)


@pytest.mark.slow
def test_the_survey_runs_on_both_nodes_of_a_ray_cluster_through_the_service():
    result = run_scenario("tests/drone/survey_cluster_scenario.py", 600)
    assert result["state"] == "succeeded", result["error"]
    workers = set(result["worker_nodes"])
    for stage in ("dense depth", "surface model", "orthophoto"):
        assert set(result["tasks_per_node"][stage]) == workers, (stage, result["tasks_per_node"])
    assert result["registered"] == 8 and result["submodels"] == 2
    assert result["coverage"]["orthophoto"] > 0.99 and result["orthophoto_bytes"] > 0
