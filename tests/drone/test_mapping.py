"""Map products from known inputs: the surface model from points, the orthophoto against the scene
seen straight from above, and the GeoTIFF/LAZ files read back with rasterio's and laspy's own readers."""
from __future__ import annotations

import cv2
import laspy
import numpy as np
import pytest
import rasterio

from workers.camera import Camera, distort_normalised
from workers.drone.dense.views import View
from workers.drone.mapfiles import DSM_NODATA, dsm_png, orthophoto_png, write_cog, write_laz
from workers.drone.orthophoto import _five, _lens_pixel, orthophoto
from workers.drone.surface import Grid, cell_medians, grid_over, surface_model
from workers.synth import Material, Plane, Scene, render
from workers.synth.survey import survey_cameras, true_orthophoto
from workers.synth.textures import ColorNoise

ORIGIN = np.array([431000.0, 5205000.0, 400.0])


def test_cell_medians_and_grid():
    grid = Grid(10.0, 20.0, 0.5, 4, 3)  # x 10..12, y 18.5..20
    pts = np.array([[10.1, 19.9, 1.0], [10.2, 19.8, 3.0], [10.3, 19.7, 2.0],  # cell (0, 0): median 2
                    [11.9, 18.6, 7.0], [11.8, 18.7, 9.0],                       # cell (2, 3): median 8
                    [50.0, 50.0, 1.0]])                                          # outside
    heights, counts = cell_medians(pts, grid)
    assert heights[0, 0] == 2.0 and heights[2, 3] == 8.0 and counts.sum() == 5
    assert np.isnan(heights[1, 1])
    assert grid.affine() == (0.5, 0.0, 10.0, 0.0, -0.5, 20.0)
    xs, ys = grid.centres()
    assert xs[0] == 10.25 and ys[0] == 19.75
    g = grid_over(np.array([[0.3, 0.3, 0], [9.7, 4.2, 0]] * 50), 0.5, margin_cells=0)
    assert g.x0 % 0.5 == 0 and g.y0 % 0.5 == 0 and g.x0 <= 0.3 and g.y0 >= 4.2


def test_surface_model_fills_gaps_inside_and_leaves_outside_empty():
    rng = np.random.default_rng(0)
    # Ground z = 0 over 40 x 30 m with a 6 m tall block, a 3 m hole without points, about 4 points a cell.
    xy = rng.uniform([0, 0], [40, 30], (20_000, 2))
    z = np.where((xy[:, 0] > 10) & (xy[:, 0] < 20) & (xy[:, 1] > 10) & (xy[:, 1] < 18), 6.0, 0.0)
    z += rng.normal(0, 0.02, len(z))
    keep = np.hypot(xy[:, 0] - 30, xy[:, 1] - 22) > 1.5
    pts = np.column_stack([xy, z])[keep]
    grid = Grid(-10.0, 40.0, 0.5, 120, 100)  # reaches 10 m beyond the points on every side
    dsm = surface_model(pts, grid)
    xs, ys = grid.centres()
    X, Y = np.meshgrid(xs, ys)
    assert np.isnan(dsm[(X < -3) | (Y > 35)]).all()  # nodata away from the flight
    block = (X > 11) & (X < 19) & (Y > 11) & (Y < 17)
    assert np.nanmedian(np.abs(dsm[block] - 6.0)) < 0.05
    ground = (X > 1) & (X < 39) & (Y > 1) & (Y < 29) & ~((X > 9) & (X < 21) & (Y > 9) & (Y < 19))
    assert np.nanmedian(np.abs(dsm[ground])) < 0.05
    hole = np.hypot(X - 30, Y - 22) < 1.2
    assert np.isfinite(dsm[hole]).all() and np.abs(dsm[hole]).max() < 0.1


def test_a_grid_no_point_reaches_takes_the_ground_level_given_over_the_extent_only():
    """A map tile at a survey's rim that one photo saw: no dense or sparse point, its footprint's cells still get a
    height (the ground level below the photos) rather than none; without that level they stay NaN."""
    grid = Grid(0.0, 10.0, 0.5, 20, 20)
    extent = np.zeros((20, 20), bool)
    extent[5:15, 2:12] = True
    none = np.zeros((0, 3))
    dsm = surface_model(none, grid, extent=extent, support=none, ground_z=401.5)
    assert (dsm[extent] == np.float32(401.5)).all() and np.isnan(dsm[~extent]).all()
    assert np.isnan(surface_model(none, grid, extent=extent, support=none)).all()
    # one sparse point is a measured height: it wins over the level given
    one = np.array([[3.0, 5.0, 399.0]])
    dsm = surface_model(none, grid, extent=extent, support=one, ground_z=401.5)
    assert np.allclose(dsm[extent], 399.0) and np.isnan(dsm[~extent]).all()


def test_orthophoto_of_flat_ground_matches_the_scene_seen_from_above():
    scene = Scene((Plane(material=Material(ColorNoise(scale=3.0, octaves=4, seed=3, contrast=200.0))),))
    cams = survey_cameras((16.0, 12.0), 30.0, width=200, height=150, fov_deg=60.0, jitter_deg=0.5, seed=2)
    views = [View(c, render(scene, c, supersample=2, with_background=False).image) for c in cams]
    grid = Grid(-10.0, 8.0, 0.15, 134, 107)
    dsm = np.zeros((grid.height, grid.width), np.float32)
    dsm[:5] = np.nan  # nodata rows stay transparent
    result = orthophoto(dsm, grid, views)
    truth_bgr, truth_z = true_orthophoto(scene, grid.x0, grid.y0, grid.gsd, grid.width, grid.height, supersample=2)
    assert np.abs(truth_z).max() < 1e-6
    alpha = result.rgba[..., 3]
    assert (alpha[:5] == 0).all() and (result.source[:5] == -1).all()
    seen = alpha > 0
    assert seen[5:].mean() > 0.95 and len(np.unique(result.source[seen])) >= 3  # several frames took part
    err = result.rgba[..., :3][seen].astype(float) - truth_bgr[..., ::-1][seen]
    psnr = 10 * np.log10(255**2 / np.mean(err**2))
    assert psnr > 28.0


def _cog(tmp_path, name, grid, array, **kw):
    """Write ``array`` (bands, H, W) through write_cog in two windows (the left and right halves) and open it."""
    half = grid.width // 2
    windows = [((0, grid.height, 0, half), array[:, :, :half]), ((0, grid.height, half, grid.width), array[:, :, half:])]
    path = tmp_path / name
    write_cog(path, grid, array.shape[0], str(array.dtype), windows, **kw)
    return rasterio.open(path)


def test_geotiffs_written_window_by_window_read_back_with_crs_transform_and_nodata(tmp_path):
    grid = Grid(-12.0, 34.0, 0.25, 80, 60)
    rgba = np.zeros((60, 80, 4), np.uint8)
    rgba[10:50, 10:70] = (200, 120, 40, 255)
    dsm = np.full((60, 80), DSM_NODATA, np.float32)
    dsm[10:50, 10:70] = ORIGIN[2] + np.linspace(0, 5, 60, dtype=np.float32)[None, :]
    alpha = [rasterio.enums.ColorInterp.red, rasterio.enums.ColorInterp.green, rasterio.enums.ColorInterp.blue,
             rasterio.enums.ColorInterp.alpha]
    with _cog(tmp_path, "o.tif", grid, np.moveaxis(rgba, 2, 0), epsg=32632, origin=ORIGIN, colorinterp=alpha) as src:
        assert src.crs.to_epsg() == 32632 and src.count == 4 and src.dtypes[0] == "uint8"
        assert src.transform.a == 0.25 and src.transform.e == -0.25
        assert (src.transform.c, src.transform.f) == (ORIGIN[0] - 12.0, ORIGIN[1] + 34.0)
        assert src.colorinterp[3] == rasterio.enums.ColorInterp.alpha
        assert src.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG"
        back = src.read()
        assert (back[3][:10] == 0).all() and (back[:, 20, 20] == [200, 120, 40, 255]).all()
        assert (back[:, 20, 60] == [200, 120, 40, 255]).all()  # from the second window
        # the world position of a pixel: the centre of row 10, column 10
        assert src.xy(10, 10) == (ORIGIN[0] - 12.0 + 10.5 * 0.25, ORIGIN[1] + 34.0 - 10.5 * 0.25)
    with _cog(tmp_path, "d.tif", grid, dsm[None], epsg=32632, origin=ORIGIN, nodata=DSM_NODATA, predictor=3) as src:
        assert src.nodata == DSM_NODATA and src.dtypes[0] == "float32" and src.crs.to_epsg() == 32632
        band = src.read(1, masked=True)
        assert band.mask[:10].all() and not band.mask[10:50, 10:70].any()
        assert band[20, 69] == pytest.approx(ORIGIN[2] + 5.0)
    with _cog(tmp_path, "a.tif", grid, np.moveaxis(rgba, 2, 0), epsg=None, origin=np.zeros(3)) as src:
        assert src.crs is None  # an arbitrary frame: no CRS claimed
    assert orthophoto_png(rgba).startswith(b"\x89PNG") and dsm_png(np.where(dsm > 0, dsm, np.nan)).startswith(b"\x89PNG")


def test_laz_written_in_chunks_reads_back_with_crs_coordinates_and_colours(tmp_path):
    pts = np.array([[0.0, 0.0, 0.0], [12.3456, -7.25, 3.5], [1.0, 2.0, 3.0]])
    bgr = np.array([[10, 20, 30], [200, 100, 0], [1, 2, 3]], np.uint8)
    path = tmp_path / "p.laz"
    assert write_laz(path, [(pts[:2], bgr[:2]), (pts[:0], bgr[:0]), (pts[2:], bgr[2:])], 32632, ORIGIN,
                     pts.min(axis=0)) == 3
    assert path.read_bytes()[:4] == b"LASF"
    las = laspy.read(str(path))
    assert las.header.point_format.id == 7 and las.header.version == "1.4" and las.header.point_count == 3
    assert las.header.parse_crs().to_epsg() == 32632
    np.testing.assert_allclose(np.column_stack([las.x, las.y, las.z]), pts + ORIGIN, atol=0.0011)
    assert list(las.red) == [30 * 257, 0, 3 * 257] and list(las.blue) == [10 * 257, 200 * 257, 1 * 257]


def test_the_service_starts_without_the_map_libraries():
    """rasterio (~0.25 s to import), laspy and pyproj load when a job writes map files, not on start-up."""
    import subprocess
    import sys

    code = ("import sys, app.main, workers.registry, workers.drone.job; "
            "print(','.join(m for m in ('rasterio', 'laspy', 'pyproj') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.strip() == ""


@pytest.mark.parametrize("dist", [[-0.09, 0.09], [-0.28, 0.07, 0.001, -0.002], [0.1, -0.2, 0.002, 0.001, 0.05]])
def test_the_orthophotos_lens_model_is_opencvs(dist):
    """The orthophoto's compiled lens (up to k3) lands where cv2.projectPoints puts each point."""
    rng = np.random.default_rng(0)
    xn, yn = rng.uniform(-0.9, 0.9, (2, 500))
    K = np.array([[702.0, 0.0, 591.9], [0.0, 705.0, 450.3], [0.0, 0.0, 1.0]])
    d = _five(np.array(dist))
    got = np.array([_lens_pixel(K[0, 0] * x + K[0, 2], K[1, 1] * y + K[1, 2], K[0, 0], K[1, 1], K[0, 2], K[1, 2], d)
                    for x, y in zip(xn, yn)])
    cv_dist = np.pad(np.array(dist, np.float64), (0, max(0, 4 - len(dist))))  # OpenCV wants four at least
    want = cv2.projectPoints(np.column_stack([xn, yn, np.ones_like(xn)]), np.zeros(3), np.zeros(3), K,
                             cv_dist)[0].reshape(-1, 2)
    np.testing.assert_allclose(got, want, atol=1e-6)


def test_an_orthophoto_uses_the_corners_the_lens_shows_beyond_the_undistorted_rectangle():
    """Barrel distortion shows more than the undistorted image's rectangle at the corners: those cells are coloured
    too (the footprint a survey's coverage is measured against is the image as the lens saw it)."""
    K = np.array([[100.0, 0.0, 79.5], [0.0, 100.0, 59.5], [0.0, 0.0, 1.0]])
    dist = np.array([-0.2, 0.0, 0.0, 0.0])
    cam = Camera("c", K, np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 10.0]), 160, 120)
    grid = Grid(-14.0, 11.0, 0.05, 560, 440)
    dsm = np.zeros((grid.height, grid.width), np.float32)
    image = np.random.default_rng(1).integers(0, 256, (120, 160, 3), np.uint8)
    out = orthophoto(dsm, grid, [View(cam, image)], dist=dist)
    xs, ys = grid.centres()
    X, Y = np.meshgrid(xs, ys)
    # a ground point at a corner of the undistorted rectangle, and one beyond it that the lens still shows
    corner = (X > 7.5) & (X < 7.9) & (Y > 5.5) & (Y < 5.9)
    assert out.rgba[..., 3][corner].all()
    u, v = distort_normalised(X.ravel() / 10.0, -Y.ravel() / 10.0, K, dist)
    shown = ((u >= 0) & (u <= 159) & (v >= 0) & (v <= 119)).reshape(X.shape)
    outside_rectangle = (np.abs(X) > 7.95) | (np.abs(Y) > 5.95)
    assert (shown & outside_rectangle).sum() > 1000
    assert (out.rgba[..., 3][shown & outside_rectangle] == 255).mean() > 0.99
    assert (out.rgba[..., 3][~shown] == 0).all()
