"""``kojima_k`` (k-camera boundary blending, eq. (6k) of workers/sweep/weighting.py) in the renderer: the same
colour as the two-camera ``kojima`` wherever at most two cameras qualify, one-camera regions untouched, three or
more cameras blended around the triple points of a two-dimensional rig, and weights that vary continuously
across the view where ``kojima``'s jump."""
import numpy as np
import pytest

from workers.synth import camera_gains, default_scene, render_views
from workers.synth.rigs import DEFAULT_TARGET
from workers.sweep.overlays import BLEND3_COLOR, BLEND_COLOR, regions_image
from workers.sweep.renderer import SweepRenderer
from workers.sweep.rig import Rig
from workers.sweep.virtual import sphere_camera, sphere_lattice
from workers.sweep.weighting import suggest_d_bnd

from .conftest import FAR, NEAR, SIZE

PLANES = 48
SPACING = 10.0  # degrees between neighbouring dome cameras


@pytest.fixture(scope="module")
def arc(capture, between_camera):
    """The 1D arc capture (conftest) seen halfway between two cameras, coloured both ways."""
    _, rig, views = capture
    r = SweepRenderer(rig, [v.image for v in views], backgrounds=[v.background for v in views])
    koj = r.render(between_camera, method="kojima", planes=PLANES, near=NEAR, far=FAR)
    return r, koj


@pytest.fixture(scope="module")
def dome():
    """A 2D rig: 9 cameras on two rows of a triangular lattice (10 deg apart) with per-camera colour gains, and two
    virtual views inside one triangle of cameras (two row-0 cameras a, b and a row-1 camera c), rendered once:
    "near" 0.2 and "mixed" 0.5 of the way from the triangle's centre (the triple point, where all three cameras
    are equally far) towards camera a. Near the triple point three cameras are within D_bnd everywhere and the
    secondary changes across the view; halfway to a, one-, two- and three-camera regions share the view."""
    target = np.array(DEFAULT_TARGET)
    lattice = sphere_lattice(SPACING, 2, 5, 20.0)
    cams = [sphere_camera(a, e, radius=2.5, target=target, size=SIZE, name=f"d{i}") for i, (a, e) in enumerate(lattice)]
    views = render_views(default_scene(), cams, gains=camera_gains(len(cams), 0.06))
    r = SweepRenderer(Rig(tuple(cams)), [v.image for v in views], backgrounds=[v.background for v in views])
    centre = (lattice[1] + lattice[2] + lattice[6]) / 3
    out = {}
    for name, s in (("near", 0.2), ("mixed", 0.5)):
        az, el = centre + s * (lattice[1] - centre)
        virtual = sphere_camera(az, el, radius=2.5, target=target, size=SIZE)
        out[name] = r.render(virtual, method="kojima", planes=PLANES, near=NEAR, far=FAR)
    return r, out


def test_kojima_k_is_kojima_on_a_one_dimensional_rig(arc):
    """Cameras on an arc: the camera behind the primary is never within D_bnd (the default blends over half
    the spacing), so at most two qualify and eq. (6k) is eq. (6) at every pixel."""
    r, koj = arc
    kk = r.reshade(koj, method="kojima_k")
    found = np.isfinite(koj.depth)
    assert kk.d_bnd == koj.d_bnd
    assert (kk.regions[found] <= 2).all()
    np.testing.assert_array_equal(kk.regions, koj.regions)
    np.testing.assert_array_equal(kk.primary, koj.primary)
    diff = np.abs(kk.image.astype(int) - koj.image.astype(int))
    assert diff.max() <= 1 and (diff == 0).mean() > 0.999  # equal up to the last bit of the weights' rounding
    w2 = r.blend_weights(koj, method="kojima")
    wk = r.blend_weights(koj, method="kojima_k")
    np.testing.assert_allclose(wk, w2, atol=1e-6)


def test_kojima_k_limits(arc, between_camera):
    r, koj = arc
    kw = dict(planes=PLANES, near=NEAR, far=FAR)
    tiny = r.reshade(koj, method="kojima_k", d_bnd=1e-12)  # only the primary within D_bnd
    np.testing.assert_array_equal(tiny.image, r.reshade(koj, method="nearest").image)
    huge = r.reshade(koj, method="kojima_k", d_bnd=2.0)  # every camera that sees the point
    w = r.blend_weights(koj, method="kojima_k", d_bnd=2.0)
    found = np.isfinite(koj.depth)
    assert (huge.regions[found] >= 2).all() and huge.regions.max() >= 4
    np.testing.assert_array_equal((w > 0).sum(axis=2), huge.regions)
    assert r.render(between_camera, method="kojima_k", **kw).d_bnd == pytest.approx(koj.d_bnd)


def test_kojima_k_blends_three_cameras_only_around_triple_points(dome):
    r, views = dome
    first = views["mixed"]
    koj = r.reshade(first, method="kojima")
    kk = r.reshade(first, method="kojima_k")
    found = np.isfinite(first.depth)
    share3 = (kk.regions[found] >= 3).mean()
    assert 0.02 < share3 < 0.9  # three-camera regions exist, and not everywhere
    assert (kk.regions[found] == 1).any()  # one-camera regions remain
    # one-camera regions stay one-camera with exactly the same colour
    one = found & (koj.regions == 1)
    assert (kk.regions[one] == 1).all()
    np.testing.assert_array_equal(kk.image[one], koj.image[one])
    # where at most two cameras qualify, eq. (6k) is eq. (6)
    two = found & (kk.regions <= 2)
    np.testing.assert_array_equal(kk.regions[two], koj.regions[two])
    assert np.abs(kk.image[two].astype(int) - koj.image[two].astype(int)).max() <= 1
    # and the kojima_k weights are what the kernel reports: sum 1, as many non-zero as the regions say
    w = r.blend_weights(first, method="kojima_k")
    np.testing.assert_allclose(w.sum(axis=2)[found], 1.0, atol=1e-5)
    assert (w[~found] == 0).all()
    np.testing.assert_array_equal((w > 0).sum(axis=2), kk.regions)
    np.testing.assert_array_equal(np.argmax(w, axis=2)[found], kk.primary[found])
    # the overlay colours the number of cameras blended
    pic = regions_image(kk.regions, kk.primary)
    assert (pic[kk.regions >= 3] == BLEND3_COLOR).all() and (pic[kk.regions == 2] == BLEND_COLOR).all()


def test_kojima_k_weights_are_continuous_across_the_view(dome):
    """Between neighbouring pixels on one surface (same plane) the cameras' rays turn a little: kojima_k's
    weights move a little, kojima's jump where a third camera overtakes the secondary inside a two-camera
    region (a seam through the view near the triple point)."""
    r, views = dome
    first = views["near"]
    same = (first.plane_index[:, 1:] == first.plane_index[:, :-1]) & (first.plane_index[:, 1:] >= 0)
    same_v = (first.plane_index[1:] == first.plane_index[:-1]) & (first.plane_index[1:] >= 0)

    def steps(method):
        w = r.blend_weights(first, method=method)
        dx = np.abs(np.diff(w, axis=1)).sum(axis=2)[same]
        dy = np.abs(np.diff(w, axis=0)).sum(axis=2)[same_v]
        return np.concatenate([dx, dy])

    koj, kk = steps("kojima"), steps("kojima_k")
    assert (koj > 0.3).sum() >= 5  # kojima's seams
    assert kk.max() < 0.25 and (kk > 0.1).sum() <= 0.2 * (koj > 0.1).sum()
    assert first.d_bnd == pytest.approx(suggest_d_bnd(np.radians(SPACING), 0.5), rel=0.2)
