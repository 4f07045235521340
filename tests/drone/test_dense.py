"""The dense reconstruction: the fused ZNCC sweep against the cost module's definitions, depth maps of a
rendered scene with exposure changes against its true depth, consistency and fusion on known geometry,
the outputs, and the job / CLI / API with ``dense``."""
from __future__ import annotations

import argparse
import io
import json
import zipfile

import cv2
import numpy as np
import pytest

from workers.common.jobctx import JobInputError
from workers.drone import cli, dense
from workers.drone.export import depth_png, ply_bytes
from workers.drone.job import run_reconstruction
from workers.drone.pipeline import DENSE_RESULT_NAMES, RESULT_NAMES
from workers.drone.params import ReconstructionParams
from workers.sweep import costs
from workers.synth.flight import flight_cameras, terrain_scene
from workers.synth.raycast import render

from tests.fakectx import FakeContext
from tests.ply import read_ply


def _random_problem(seed, h=23, w=31, n=3, planes=7):
    rng = np.random.default_rng(seed)
    ref = rng.uniform(0, 255, (h, w)).astype(np.float32)
    imgs = rng.uniform(0, 255, (n, h + 3, w - 2)).astype(np.float32)
    Q = np.stack([np.array([[1.0, 0.02, 1.5], [0.01, 0.98, -2], [1e-4, 2e-4, 1]]) + rng.normal(0, 0.01, (3, 3))
                  for _ in range(n)])
    B = rng.normal(0, 3, (n, 3))
    B[:, 2] *= 0.01
    return ref, imgs, Q, B, np.linspace(0.5, 2.0, planes)


def _composed(ref, imgs, Q, B, s, r, k, min_std):
    """The sweep written with the cost module's functions and plain-numpy resampling."""
    h, w = ref.shape
    per = []
    for n in range(len(imgs)):
        smp, ok = zip(*(dense.plane_samples(imgs[n], Q[n], B[n], sj, h, w) for sj in s))
        per.append(costs.zncc_cost(ref, np.stack(smp, 2), r, min_std, np.stack(ok, 2)))
    return costs.best_k_mean(np.stack(per), k)


@pytest.mark.parametrize("r,k", [(0, 1), (1, 2), (2, 3)])
def test_fused_sweep_equals_the_cost_module(r, k):
    ref, imgs, Q, B, s = _random_problem(r)
    best, value, offset, volume = dense.zncc_sweep(ref, imgs, Q, B, s, radius=r, k=k, min_std=1.0, keep_volume=True)
    want = _composed(ref, imgs, Q, B, s, r, k, 1.0)
    fin = np.isfinite(want)
    assert (np.isfinite(volume) == fin).all()
    np.testing.assert_allclose(volume[fin], want[fin], atol=1e-4)
    wb, wv, wo = costs.winner(want)
    assert (best == wb).mean() > 0.99
    same = best == wb
    np.testing.assert_allclose(offset[same], wo[same], atol=2e-3)


def test_tiles_and_windows_restrict_the_search():
    ref, imgs, Q, B, s = _random_problem(7, planes=9)
    full, _, _, vol = dense.zncc_sweep(ref, imgs, Q, B, s, radius=1, k=2, keep_volume=True, tile=(5, 7))
    lo = np.full(ref.shape, 2, np.int32)
    hi = np.full(ref.shape, 5, np.int32)
    best, value, _, _ = dense.zncc_sweep(ref, imgs, Q, B, s, radius=1, k=2, windows=(lo, hi), tile=(6, 8))
    want = np.argmin(vol[:, :, 2:6], axis=2) + 2
    fin = np.isfinite(vol[:, :, 0])
    assert (best[fin] == want[fin]).all()
    lo[:] = 3
    hi[:] = 2  # no pixel needs a plane: nothing searched
    best, value, _, _ = dense.zncc_sweep(ref, imgs, Q, B, s, radius=1, k=2, windows=(lo, hi))
    assert (best == -1).all() and np.isinf(value).all()


def test_sweep_geometry_maps_a_plane_point_into_the_other_view():
    cams = flight_cameras(3, length=6.0, altitude=20.0, width=64, height=48, seed=1)
    views = [dense.View(c, np.zeros((48, 64, 3), np.uint8)) for c in cams]
    Q, B = dense.sweep_geometry(views[0], views[1:])
    X = views[0].camera.backproject(np.array([[30.0, 20.0]]), 17.0)
    uv, _ = views[2].camera.project(X)
    hmg = Q[1] @ np.array([30.0, 20.0, 1.0]) + B[1] / 17.0
    np.testing.assert_allclose(hmg[:2] / hmg[2], uv[0], atol=1e-9)


@pytest.fixture(scope="module")
def town():
    """9 rendered views of the synthetic town with exposure gains from 0.75 to 1.3, and their true depths."""
    scene = terrain_scene(3, extent=80.0, n_buildings=10, n_trees=12)
    cams = flight_cameras(9, length=16.0, altitude=25.0, sway=2.0, width=256, height=192, fov_deg=70, seed=3)
    gains = [1.0, 1.3, 0.75, 1.15, 0.85, 1.25, 0.8, 1.1, 0.9]
    views, truth = [], []
    for c, g in zip(cams, gains):
        r = render(scene, c, gain=g, with_background=False)
        views.append(dense.View(c, r.image))
        truth.append(r.depth)
    return views, truth


def _range(truth):
    d = truth[np.isfinite(truth) & (truth > 0)]
    return float(d.min()) * 0.8, float(d.max()) * 1.25


@pytest.mark.parametrize("aggregation,c2f", [("window", False), ("window", True), ("sgm", False)])
def test_depth_map_of_a_rendered_town_with_exposure_changes(town, aggregation, c2f):
    views, truth = town
    near, far = _range(truth[4])
    dm = dense.depth_map(views[4], [views[i] for i in range(9) if i != 4], near, far, planes=64, radius=2, k=4,
                         aggregation=aggregation, coarse_to_fine=c2f)
    ok = dm.depth > 0
    rel = np.abs(dm.depth[ok] - truth[4][ok]) / truth[4][ok]
    assert ok.mean() > 0.6
    assert np.median(rel) < 0.005 and (rel < 0.02).mean() > 0.9


def test_zncc_beats_the_variance_under_exposure_changes(town):
    """The same sweep scored by the renderer's cost (colour variance over the window) on the same views
    loses to ZNCC when the frames differ in exposure."""
    views, truth = town
    ref, nbrs = views[4], [views[i] for i in (2, 3, 5, 6)]
    near, far = _range(truth[4])
    s = dense.inverse_depth_planes(near, far, 48)
    Q, B = dense.sweep_geometry(ref, nbrs)
    h, w = truth[4].shape
    ssd = np.zeros((h, w, len(s)), np.float32)
    samples = []
    for n, v in enumerate(nbrs):
        g = v.gray()
        samples.append(np.stack([dense.plane_samples(g, Q[n], B[n], sj, h, w)[0] for sj in s], 2))
    stack = np.stack([np.broadcast_to(ref.gray()[:, :, None], ssd.shape)] + samples)
    ssd = ((stack - stack.mean(0)) ** 2).sum(0).astype(np.float32)
    var_best, _, _ = costs.winner(costs.windowed_variance(ssd, np.full_like(ssd, 5.0), 2))
    zn_best, _, _, _ = dense.zncc_sweep(ref.gray(), np.stack([v.gray() for v in nbrs]), Q, B, s, 2, 4)
    true_j = np.argmin(np.abs(1.0 / truth[4][:, :, None] - s[None, None, :]), axis=2)
    good = np.isfinite(truth[4])
    zn_ok = (np.abs(zn_best - true_j) <= 1)[good].mean()
    var_ok = (np.abs(var_best - true_j) <= 1)[good].mean()
    assert zn_ok > var_ok + 0.05, (zn_ok, var_ok)


def test_consistency_and_fusion_on_true_depths(town):
    views, truth = town
    depths = [np.where(np.isfinite(t), t, 0).astype(np.float32) for t in truth[2:7]]
    vs = views[2:7]
    nb = [[j for j in range(5) if j != i] for i in range(5)]
    ag = dense.consistency(vs[2], depths[2], [vs[j] for j in nb[2]], [depths[j] for j in nb[2]])
    assert (ag.count[depths[2] > 0] >= 3).mean() > 0.8  # the rest: near the border, seen by fewer
    wrong = depths[0] * 1.05  # 5 % off everywhere: no other frame agrees
    ag = dense.consistency(vs[0], wrong, vs[1:], depths[1:])
    assert (ag.count[wrong > 0] == 1).mean() > 0.99
    cloud = dense.fuse(vs, depths, nb, min_views=3)
    assert len(cloud) > 0.5 * depths[0].size and (cloud.views >= 3).all()
    # every fused point lies on the surface: its depth in the middle view matches the true depth there
    uv, z = vs[2].camera.project(cloud.points)
    u, v = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
    inside = (u >= 0) & (v >= 0) & (u < 256) & (v < 192) & (z > 0)
    t = depths[2][v[inside], u[inside]]
    close = np.abs(z[inside] - t) / np.maximum(t, 1e-9) < 0.02
    assert close.mean() > 0.8
    # normals are unit and face the cameras; the open ground faces up (+z in this world)
    np.testing.assert_allclose(np.linalg.norm(cloud.normals, axis=1), 1.0, atol=1e-4)
    assert np.median(cloud.normals[:, 2]) > 0.9
    # no pixel is fused twice: fewer points than pixels with a depth
    assert len(cloud) < sum(int((d > 0).sum()) for d in depths) / 2


def test_compiled_fusion_agrees_with_the_numpy_consistency_and_normals(town):
    views, truth = town
    rng = np.random.default_rng(0)
    depths = [np.where(np.isfinite(t), t * (1 + rng.normal(0, 0.003, t.shape)), 0).astype(np.float32)
              for t in truth[2:7]]
    vs = views[2:7]
    ag = dense.consistency(vs[0], depths[0], vs[1:], depths[1:])
    cloud = dense.fuse(vs, depths, [[1, 2, 3, 4], [], [], [], []], min_views=3)  # view 0 alone starts points
    keep = ag.count >= 3
    ys, xs = np.nonzero(keep)
    assert len(cloud) == len(ys)
    np.testing.assert_array_equal(cloud.views, ag.count[ys, xs])
    np.testing.assert_allclose(cloud.normals, dense.camera_normals(vs[0], depths[0])[ys, xs], atol=1e-4)
    X = vs[0].camera.backproject(np.column_stack([xs, ys]), depths[0][ys, xs])
    for ok, Xn in zip(ag.agree, ag.X):
        X[ok[keep[ag.ys, ag.xs]]] += Xn[keep[ag.ys, ag.xs]][ok[keep[ag.ys, ag.xs]]]
    np.testing.assert_allclose(cloud.points, X / ag.count[ys, xs][:, None], rtol=1e-5, atol=1e-4)


def test_camera_normals_of_a_tilted_plane():
    K = np.array([[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]])
    view = dense.View.from_pose("v", np.zeros((48, 64, 3), np.uint8), K, np.eye(3), np.zeros(3))
    ys, xs = np.mgrid[0:48, 0:64].astype(np.float64)
    rays = np.stack([(xs - 31.5) / 100, (ys - 23.5) / 100, np.ones_like(xs)], -1)
    n = np.array([0.3, -0.2, -1.0])
    n /= np.linalg.norm(n)
    depth = (-10.0 / (rays @ n)).astype(np.float32)  # the plane n . X = 10 (camera at the origin)
    got = dense.camera_normals(view, depth)
    np.testing.assert_allclose(got[5:-5, 5:-5], np.broadcast_to(n, got[5:-5, 5:-5].shape), atol=1e-3)


def test_neighbours_prefer_a_useful_baseline_and_ranges_come_from_the_points():
    K = np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
    img = np.broadcast_to(np.zeros((1, 1, 3), np.uint8), (480, 640, 3))
    # cameras looking down +z at points around z = 10, 0 / 0.1 / 0.9 / 3 units to the side
    views = [dense.View.from_pose(str(i), img, K, np.eye(3), -np.array([x, 0, 0.0]))
             for i, x in enumerate((0, 0.1, 0.9, 3.0))]
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-2, 2, 300), rng.uniform(-1.5, 1.5, 300), rng.uniform(9, 11, 300)])
    seen = [dense.visible_points(v.camera, pts) for v in views]
    # ~5 deg first, then ~17 deg (a wide baseline still measures depth), never ~0.6 deg
    assert dense.select_neighbours(views, pts, seen, 0, 2) == [2, 3]
    near, far = dense.depth_range(views[0].camera, pts, margin=0.25, percentile=0)
    assert near == pytest.approx(pts[seen[0], 2].min() / 1.25) and far == pytest.approx(pts[seen[0], 2].max() * 1.25)
    assert dense.depth_range(views[0].camera, pts[:5]) is None


def test_depth_png_and_ply_round_trip():
    depth = np.array([[0.0, 1.5], [10.0, 7.25]], np.float32)
    png, scale = depth_png(depth, 12.0)
    levels = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert levels.dtype == np.uint16 and levels[0, 0] == 0
    np.testing.assert_allclose(levels * scale, depth, atol=scale)
    cloud = dense.DenseCloud(np.array([[1, 2, 3], [4, 5, 6]], np.float32),
                             np.array([[10, 20, 30], [1, 2, 3]], np.uint8),
                             np.array([[0, 0, 1], [1, 0, 0]], np.float32), np.array([3, 5], np.uint8))
    v = read_ply(ply_bytes(cloud.points, cloud.colors, cloud.normals, cloud.views))
    np.testing.assert_array_equal(np.column_stack([v["x"], v["y"], v["z"]]), cloud.points)
    np.testing.assert_array_equal(np.column_stack([v["nx"], v["ny"], v["nz"]]), cloud.normals)
    np.testing.assert_array_equal(np.column_stack([v["blue"], v["green"], v["red"]]), cloud.colors)
    np.testing.assert_array_equal(v["views"], cloud.views)


# --- the job, the CLI, the API ---------------------------------------------------------------
DENSE_FAST = {"max_features": 1000, "dense": True, "dense_planes": 48, "dense_frames": 12, "dense_neighbours": 4,
              "dense_best_k": 2}


def _intrinsics(flight):
    K = flight.K
    return {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}


def test_job_with_dense_writes_a_dense_cloud(tmp_path, flight):
    ctx = FakeContext(tmp_path, {**_intrinsics(flight), **DENSE_FAST}, {"media": flight.path.read_bytes()})
    summary = run_reconstruction(ctx)
    for name in RESULT_NAMES + DENSE_RESULT_NAMES:
        assert ctx.result_path(name).stat().st_size > 0, name
    report = json.loads(ctx.result_path("report.json").read_text())
    d = report["dense"]
    assert d["depth_maps"] == 12 and summary["dense_points"] == d["points"] > 20 * report["points"]
    assert d["views_per_point"]["at_least_3"] == 1.0  # min_views 3
    ply = read_ply(ctx.result_path("dense.ply").read_bytes())
    assert len(ply) == d["points"]
    with zipfile.ZipFile(io.BytesIO(ctx.result_path("depth.zip").read_bytes())) as zf:
        assert sorted(zf.namelist()) == sorted(f["file"] for f in d["frames"])
        first = d["frames"][0]
        level = cv2.imdecode(np.frombuffer(zf.read(first["file"]), np.uint8), cv2.IMREAD_UNCHANGED)
    assert level.dtype == np.uint16 and level.shape == (240, 320)
    depth = level * first["depth_scale"]
    assert first["near"] <= np.median(depth[level > 0]) <= first["far"]
    preview = cv2.imdecode(np.frombuffer(ctx.result_path("preview.png").read_bytes(), np.uint8), 1)
    assert preview.shape[0] == 2 * 420  # sparse row + dense row
    stages = [s for _, s in ctx.progress_calls]
    assert "dense depth 0/12" in stages and "dense depth 12/12" in stages
    assert any(s.startswith("surface model") and s.endswith("tiles") for s in stages)  # fusion per ground tile
    fractions = [f for f, _ in ctx.progress_calls]
    assert fractions == sorted(fractions)
    # the dense points agree with the sparse ones: most sparse points have a dense point close by
    from scipy.spatial import cKDTree

    sparse = np.array([[float(x) for x in ln.split()[1:4]] for ln in
                       ctx.result_path("points3D.txt").read_text().splitlines() if not ln.startswith("#")])
    dist, _ = cKDTree(np.column_stack([ply["x"], ply["y"], ply["z"]])).query(sparse)
    scale = np.median(np.linalg.norm(sparse - np.median(sparse, 0), axis=1))
    assert np.median(dist) < 0.02 * scale


@pytest.mark.parametrize("fields, message", [
    ({"dense_window": 4}, "odd"),
    ({"dense_best_k": 9}, "dense_best_k"),
    ({"dense_min_views": 10}, "dense_min_views"),
    ({"dense_planes": 2}, "greater than or equal"),
    ({"dense_aggregation": "median"}, "window"),
])
def test_bad_dense_params_are_refused(fields, message):
    with pytest.raises(ValueError, match=message):
        ReconstructionParams(**fields)


def test_sgm_volume_limit_is_a_user_error(tmp_path, flight, monkeypatch):
    monkeypatch.setenv("SWEEPCAST_MAX_DENSE_VOLUME", "1000000")  # the smallest limit the setting allows
    ctx = FakeContext(tmp_path, {**_intrinsics(flight), **DENSE_FAST, "dense_aggregation": "sgm"},
                      {"media": flight.path.read_bytes()})
    with pytest.raises(JobInputError, match="SWEEPCAST|limit"):
        run_reconstruction(ctx)


def test_cli_reconstruct_dense(tmp_path, flight, capsys):
    parser = argparse.ArgumentParser()
    cli.register(parser.add_subparsers())
    out = tmp_path / "rec"
    args = parser.parse_args(["reconstruct", str(flight.path), "--intrinsics", flight.intrinsics, "--out", str(out),
                              "--dense", "--dense-planes", "32", "--dense-scale", "0.5",
                              "--params", json.dumps({"max_features": 1000, "dense_frames": 8})])
    assert args.func(args) == 0
    assert {p.name for p in out.iterdir()} >= set(RESULT_NAMES + DENSE_RESULT_NAMES)
    report = json.loads((out / "report.json").read_text())
    assert report["dense"]["resolution"] == [160, 120] and "dense" in report["timings_s"]
    assert "dense points" in capsys.readouterr().out


def test_api_refuses_bad_dense_params(client_factory):
    client = client_factory()
    r = client.post("/v1/reconstructions", files={"media": ("f.mp4", b"x" * 100, "video/mp4")},
                    data={"params": json.dumps({"fx": 300, "fy": 300, "cx": 160, "cy": 120, "dense": True,
                                                "dense_window": 6})})
    assert r.status_code == 422 and "dense_window" in r.json()["detail"]
