"""The renderer on a generated scene, against the scene's exact ground truth."""
from dataclasses import replace

import numpy as np
import pytest
from pydantic import ValidationError

from workers.synth import arc_angles, arc_camera, render
from workers.common.imagemetrics import psnr
from workers.sweep.reference import reference_sweep
from workers.sweep.renderer import RenderOptions, SweepRenderer
from workers.sweep.rig import RigError
from workers.sweep.weighting import suggest_d_bnd

from .conftest import FAR, NEAR, plane_step_at

PLANES = 48


@pytest.fixture(scope="module")
def renderer(capture):
    _, rig, views = capture
    return SweepRenderer(rig, [v.image for v in views], backgrounds=[v.background for v in views])


def test_silhouettes_from_background_match_the_truth(renderer, capture):
    _, _, views = capture
    for sil, v in zip(renderer.silhouettes(), views):
        assert (sil | ~v.silhouette).mean() > 0.995  # the dilated hull keeps the object
        assert (sil & ~v.silhouette).sum() < 0.5 * v.silhouette.sum()


@pytest.mark.parametrize("method", ["kojima", "nearest", "global"])
def test_virtual_camera_at_a_rig_camera_reproduces_its_image(renderer, capture, method):
    _, rig, views = capture
    cam = rig[3]
    out = renderer.render(cam, method=method, planes=PLANES, near=NEAR, far=FAR)
    found = np.isfinite(out.depth)
    assert (found & views[3].silhouette).sum() > 0.97 * views[3].silhouette.sum()
    diff = np.abs(out.image.astype(int) - views[3].image.astype(int))[found]
    assert diff.max() <= 1  # the camera's own ray samples its own pixel at any depth
    assert (out.primary[found] == 3).all()
    assert (out.regions[found] == 1).all()
    assert np.isinf(out.depth[~renderer.silhouettes()[3]]).all()  # outside the hull: nothing
    assert (out.image[~found] == 0).all() and (out.regions[~found] == 0).all()


def test_depth_is_within_the_plane_spacing_of_the_truth(renderer, capture, between_camera):
    scene = capture[0]
    gt = render(scene, between_camera)
    out = renderer.render(between_camera, planes=PLANES, near=NEAR, far=FAR)
    ok = gt.silhouette & np.isfinite(out.depth)
    assert ok.sum() > 0.95 * gt.silhouette.sum()
    err = np.abs(out.depth[ok] - gt.depth[ok])
    step = plane_step_at(float(np.median(gt.depth[ok])), PLANES)
    assert np.median(err) < step
    assert np.mean(err < 3 * step) > 0.8


def test_view_between_cameras_matches_the_truth(renderer, capture, between_camera):
    scene = capture[0]
    gt = render(scene, between_camera)
    for method in ("kojima", "nearest", "ulr", "global"):
        out = renderer.render(between_camera, method=method, planes=PLANES, near=NEAR, far=FAR)
        ok = gt.silhouette & np.isfinite(out.depth)
        assert psnr(out.image, gt.image, ok) > 20.0, method


def test_kojima_regions_and_its_limits(renderer, between_camera):
    kw = dict(planes=PLANES, near=NEAR, far=FAR)
    # a quarter of the way from camera 2 to 3: the blend band (half the spacing) starts here
    a = arc_angles(6, 75.0)
    quarter = arc_camera(float(a[2] + 0.25 * (a[3] - a[2])), width=160, height=120, name="q")
    koj = renderer.render(quarter, method="kojima", d_bnd=suggest_d_bnd(np.radians(a[3] - a[2]), 0.5), **kw)
    found = np.isfinite(koj.depth)
    frac2 = (koj.regions[found] == 2).mean()
    assert set(np.unique(koj.regions[found])) == {1, 2} and 0.05 < frac2 < 0.95  # both kinds of region
    assert set(np.unique(koj.primary[found & (koj.regions == 1)])) == {2}
    auto = renderer.render(quarter, method="kojima", **kw)  # D_bnd from the camera spacing
    assert auto.d_bnd == pytest.approx(koj.d_bnd, rel=0.3)
    assert renderer.render(quarter, method="nearest", **kw).d_bnd is None
    # tiny D_bnd: every pixel is a one-camera region, i.e. the per-pixel nearest camera
    tiny = renderer.render(between_camera, method="kojima", d_bnd=1e-12, **kw)
    nearest = renderer.render(between_camera, method="nearest", **kw)
    np.testing.assert_array_equal(tiny.image, nearest.image)
    # re-colouring a result gives what a full render with that method gives
    np.testing.assert_array_equal(renderer.reshade(tiny, method="nearest").image, nearest.image)
    assert renderer.reshade(tiny, method="ulr", k=2).depth is tiny.depth
    # huge D_bnd: two-camera regions everywhere
    huge = renderer.render(between_camera, method="kojima", d_bnd=2.0, **kw)
    found = np.isfinite(huge.depth)
    assert (huge.regions[found] == 2).all()
    ulr = renderer.render(between_camera, method="ulr", k=3, **kw)
    assert (ulr.regions[found] <= 3).all() and (ulr.regions[found] == 3).mean() > 0.5
    glob = renderer.render(between_camera, method="global", **kw)
    assert len(np.unique(glob.primary[found])) >= 2  # primary still reports the nearest camera


def test_kernel_agrees_with_the_straightforward_sweep(capture, between_camera):
    _, rig, views = capture
    r = SweepRenderer(rig, [v.image for v in views])  # no hull: the reference has none
    cam = between_camera.scaled(0.5)
    out = r.render(cam, planes=24, near=NEAR, far=FAR, subpixel_bits=5, aggregation="none")
    best_ref, _ = reference_sweep(list(rig.cameras), [v.image for v in views], cam, out.planes)
    best = np.full(out.depth.shape, -1)
    ok = np.isfinite(out.depth)
    best[ok] = np.argmin(np.abs(out.depth[ok, None] - out.planes[None, :]), axis=1)
    seen = best_ref >= 0
    assert (best[seen] == best_ref[seen]).mean() >= 0.99


def test_coarse_to_fine_stays_close_to_the_full_search(renderer, between_camera):
    kw = dict(planes=PLANES, near=NEAR, far=FAR, aggregation="none")  # the winner-take-all search at both levels
    full = renderer.render(between_camera, **kw)
    c2f = renderer.render(between_camera, coarse_to_fine=True, **kw)
    both = np.isfinite(full.depth) & np.isfinite(c2f.depth)
    assert both.sum() > 0.9 * np.isfinite(full.depth).sum()
    assert (full.depth[both] == c2f.depth[both]).mean() > 0.85
    assert "coarse_ms" in c2f.timings and "sweep_ms" in c2f.timings


def test_truncated_cost_renders(renderer, capture, between_camera):
    gt = render(capture[0], between_camera)
    out = renderer.render(between_camera, planes=PLANES, near=NEAR, far=FAR, consistency="truncated", truncation=25)
    ok = gt.silhouette & np.isfinite(out.depth)
    assert psnr(out.image, gt.image, ok) > 20.0


def test_new_frames_replace_the_old(capture):
    _, rig, views = capture
    r = SweepRenderer(rig, [v.image for v in views], backgrounds=[v.background for v in views])
    before = r.render(rig[2], method="nearest", planes=16, near=NEAR, far=FAR)
    r.set_frames([np.ascontiguousarray(v.image[..., ::-1]) for v in views])  # swap B and R
    after = r.render(rig[2], method="nearest", planes=16, near=NEAR, far=FAR)
    ok = np.isfinite(before.depth) & np.isfinite(after.depth)
    np.testing.assert_array_equal(after.image[ok], before.image[ok][:, ::-1])


def test_bad_options_are_rejected(renderer, between_camera):
    with pytest.raises(ValidationError):
        renderer.render(between_camera, method="best")
    with pytest.raises(ValidationError):
        renderer.render(between_camera, d_bnd=0.0)
    with pytest.raises(ValidationError):
        RenderOptions(planes=1)
    with pytest.raises(RigError, match="near/far"):
        renderer.render(between_camera, near=3.0, far=2.0)
    no_hull = SweepRenderer(renderer.rig, [np.zeros((c.height, c.width, 3), np.uint8) for c in renderer.rig.cameras])
    with pytest.raises(RigError, match="visual_hull"):
        no_hull.render(between_camera, visual_hull=True, near=NEAR, far=FAR)


def test_distorted_cameras_are_undistorted(capture):
    _, rig, views = capture
    import cv2

    from workers.camera import Camera
    dist = np.array([-0.3, 0.08, 0.0, 0.0, 0.0])
    smooth = [cv2.GaussianBlur(v.image, (0, 0), 1.5) for v in views]  # resampling twice must not dominate
    cams, imgs = [], []
    for cam, img in zip(rig.cameras, smooth):
        # make the image a distorting lens would have taken: distorted pixel -> ideal pixel -> sample
        grid = cam.pixel_grid().reshape(-1, 1, 2)
        ideal = cv2.undistortPoints(grid, cam.K, dist, P=cam.K).reshape(cam.height, cam.width, 2).astype(np.float32)
        imgs.append(cv2.remap(img, ideal[..., 0], ideal[..., 1], cv2.INTER_LINEAR))
        cams.append(Camera(cam.name, cam.K, cam.R, cam.t, cam.width, cam.height, dist))
    kw = dict(method="nearest", planes=24, near=NEAR, far=FAR)
    truth = smooth[2]
    undistorted = SweepRenderer(cams, imgs).render(rig[2], **kw)
    ignored = SweepRenderer(rig, imgs).render(rig[2], **kw)  # the same images taken as pinhole
    inner = np.zeros(truth.shape[:2], bool)
    inner[15:-15, 20:-20] = True
    ok = inner & np.isfinite(undistorted.depth) & np.isfinite(ignored.depth)
    assert ok.sum() > 0.5 * inner.sum()
    assert psnr(undistorted.image, truth, ok) > psnr(ignored.image, truth, ok) + 3.0


def test_kojima_renders_a_rig_whose_cameras_share_one_place(capture, between_camera):
    """Duplicated poses (templeSparseRing has them) leave no camera spacing: D_bnd falls back, no error."""
    _, rig, views = capture
    twins = SweepRenderer([rig.cameras[2], replace(rig.cameras[2], name="twin")], [views[2].image] * 2)
    out = twins.render(between_camera, method="kojima", planes=8, near=NEAR, far=FAR)
    assert out.d_bnd == pytest.approx(suggest_d_bnd(np.radians(10.0), 0.5))
    assert np.isfinite(out.depth).any()
