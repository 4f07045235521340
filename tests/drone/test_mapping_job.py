"""A drone flight in, a map out: a small synthetic nadir survey (geotagged JPEGs through a lens with
distortion, no intrinsics given) through the job, and the GeoTIFFs and the LAZ read back with rasterio's
and laspy's own readers against the scene's truth."""
from __future__ import annotations

import argparse
import io
import json
import zipfile

import cv2
import laspy
import numpy as np
import pytest
import rasterio

from tests.fakectx import FakeContext
from workers.drone import cli
from workers.drone.job import run_reconstruction
from workers.drone.surface import Grid
from workers.drone.survey.ground import footprint_mask
from workers.synth.flight import render_flight
from workers.synth.survey import survey_cameras, survey_scene, true_orthophoto, write_geotagged_stills

ORIGIN = (431000.0, 5205000.0, 400.0)  # UTM 32N: the scene's (0, 0, 0)
EPSG = 32632


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    scene = survey_scene(2, extent=120.0, n_buildings=6, n_trees=10)
    cams = survey_cameras((24.0, 20.0), 60.0, width=320, height=240, fov_deg=70.0, forward_overlap=0.85,
                          side_overlap=0.75, jitter_deg=1.0, dist=(-0.04, 0.0, 0.0, 0.0), seed=2)
    frames = render_flight(scene, cams, noise_sigma=1.0, supersample=2, seed=2)
    folder = tmp_path_factory.mktemp("survey") / "stills"
    paths = write_geotagged_stills(folder, frames, cams, EPSG, ORIGIN, focal_35mm=25)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for p in paths:
            zf.write(p, f"flight/{p.name}")
    return scene, cams, frames, buf.getvalue()


def _true_footprints(cams):
    """Each camera's image border, through its lens, on the ground z = 0 (scene frame): (K, 2) x, y."""
    out = []
    for cam in cams:
        w, h = cam.width - 1, cam.height - 1
        s = np.linspace(0, 1, 16, endpoint=False)
        border = np.concatenate([np.column_stack([s * w, 0 * s]), np.column_stack([w + 0 * s, s * h]),
                                 np.column_stack([(1 - s) * w, h + 0 * s]), np.column_stack([0 * s, (1 - s) * h])])
        rays = cam.rays(border)
        out.append(cam.center[:2] + (-cam.center[2] / rays[:, 2])[:, None] * rays[:, :2])
    return out


def _psnr(a, b):
    return 10 * np.log10(255.0**2 / np.mean((a.astype(float) - b.astype(float)) ** 2))


def test_geotagged_stills_give_a_georeferenced_orthophoto_dsm_and_laz(tmp_path, survey):
    scene, cams, _, data = survey
    ctx = FakeContext(tmp_path, {}, {"media": data})  # no parameters at all
    summary = run_reconstruction(ctx)
    assert summary["georeferenced"] and summary["epsg"] == EPSG
    assert {"orthophoto.tif", "orthophoto.png", "dsm.tif", "dsm.png", "points.laz"} <= set(summary["results"])
    stages = {s.split(" ")[0] for _, s in ctx.progress_calls}
    assert {"georeference", "surface", "orthophoto", "dense"} <= stages
    report = json.loads(ctx.result_path("report.json").read_text())
    lens = report["intrinsics"]
    assert lens["source"] == "exif_35mm" and lens["self_calibrated"]
    assert lens["fx"] == pytest.approx(cams[0].K[0, 0], rel=0.03)
    assert report["georeference"]["camera_position_error_m"]["rmse"] < 0.5

    with rasterio.open(ctx.result_path("orthophoto.tif")) as src:
        assert src.crs.to_epsg() == EPSG and src.count == 4
        assert src.transform.b == 0 and src.transform.d == 0 and src.transform.e == -src.transform.a
        gsd = src.transform.a
        assert gsd == pytest.approx(report["mapping"]["gsd"])
        # The flight's centre lies inside the raster, and the raster around the surveyed area only.
        assert src.bounds.left < ORIGIN[0] < src.bounds.right and src.bounds.bottom < ORIGIN[1] < src.bounds.top
        assert src.bounds.right - src.bounds.left < 120
        rgba = src.read()
        x0, y0 = src.transform.c - ORIGIN[0], src.transform.f - ORIGIN[1]
    alpha = rgba[3] > 0
    assert alpha[rgba.shape[1] // 2, rgba.shape[2] // 2] and not alpha.all()  # nodata outside the flight
    truth_bgr, truth_z = true_orthophoto(scene, x0, y0, gsd, rgba.shape[2], rgba.shape[1], supersample=2)
    ortho = np.moveaxis(rgba[:3], 0, 2)
    # In the right place: against the scene seen from above where it lies in UTM (a shift of one metre
    # would cost more than 8 dB here).
    assert _psnr(ortho[alpha], truth_bgr[..., ::-1][alpha]) > 22.0

    with rasterio.open(ctx.result_path("dsm.tif")) as src:
        assert src.crs.to_epsg() == EPSG and src.dtypes[0] == "float32" and src.nodata == -9999.0
        assert src.transform == rasterio.transform.Affine(gsd, 0, x0 + ORIGIN[0], 0, -gsd, y0 + ORIGIN[1])
        band = src.read(1, masked=True)
    assert band.mask.any() and (~band.mask).mean() > 0.3
    dsm, known = band.data.astype(float), ~band.mask
    # The DSM covers the ground every photo saw: the union of their true footprints, whatever few photos saw.
    grid = Grid(x0, y0, gsd, band.shape[1], band.shape[0])
    views = sum(footprint_mask(grid, [p]).astype(int) for p in _true_footprints(cams))
    assert known[views > 0].mean() > 0.99
    err = (dsm - ORIGIN[2] - truth_z)[known]
    # Heights in metres of the recorded altitude. Their offset follows the focal length, which a flat
    # scene from above hardly shows: the EXIF's integer 25 mm is 1.1 % long, 0.66 m at 60 m.
    offset = float(np.median(err))
    assert abs(offset) < 1.0
    assert np.median(np.abs(err - offset)) < gsd
    # Where the dense pass can see them (a reference and its best dense_best_k = 4 neighbours), buildings and trees
    # stand up (a little rounded by the 5 px windows); where fewer photos did, their height is what the sparse points
    # and the fill give.
    tops = known & (views >= 5) & (truth_z > 3.0)
    assert np.median((dsm - ORIGIN[2] - offset)[tops]) > 0.8 * np.median(truth_z[tops])

    las = laspy.read(str(ctx.result_path("points.laz")))
    assert las.header.parse_crs().to_epsg() == EPSG
    assert abs(np.median(las.x) - ORIGIN[0]) < 20 and abs(np.median(las.y) - ORIGIN[1]) < 20
    assert abs(np.median(las.z) - ORIGIN[2]) < 3 and las.red.max() > 255  # 16-bit colours


def test_stills_without_gps_give_an_orthophoto_in_an_arbitrary_frame_from_the_cli(tmp_path, survey, capsys):
    _, _, frames, _ = survey
    folder = tmp_path / "plain"
    folder.mkdir()
    for i, img in enumerate(frames):
        cv2.imwrite(str(folder / f"img_{i:02d}.png"), img)  # PNGs: no EXIF, no GPS
    parser = argparse.ArgumentParser()
    cli.register(parser.add_subparsers())
    out = tmp_path / "out"
    args = parser.parse_args(["reconstruct", str(folder), "--orthophoto", "--no-dsm", "--out", str(out)])
    assert args.func(args) == 0
    assert (out / "orthophoto.tif").exists() and not (out / "dsm.tif").exists() and not (out / "points.laz").exists()
    report = json.loads((out / "report.json").read_text())
    assert report["intrinsics"]["source"] == "default_fov"
    assert not report["georeference"]["georeferenced"] and "arbitrary" in report["georeference"]["frame"]
    with rasterio.open(out / "orthophoto.tif") as src:
        assert src.crs is None and src.read(4).max() == 255
    assert "world frame" in capsys.readouterr().out


def test_georeference_required_without_gps_fails_with_a_reason(tmp_path, survey):
    _, _, frames, _ = survey
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for i, img in enumerate(frames[:4]):
            zf.writestr(f"img_{i}.png", cv2.imencode(".png", img)[1].tobytes())
    ctx = FakeContext(tmp_path, {"georeference": "required"}, {"media": buf.getvalue()})
    with pytest.raises(Exception, match="no GPS positions"):
        run_reconstruction(ctx)
