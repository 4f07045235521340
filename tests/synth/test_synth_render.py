"""workers.synth: exact depth, silhouettes, background images and rigs against analytic answers."""
import numpy as np

from workers.camera import Camera
from workers.synth import (Box, Checker, ColorNoise, Material, Plane, Scene, Solid, Sphere, arc_angles,
                           camera_gains, city_scene, default_arc_rig, default_scene, fractal_noise, render)


def _cam(w=64, h=48):
    return Camera.look_at("c", [0, -4, 0], [0, 0, 0], [0, 0, 1], fov_deg=40, width=w, height=h)


def test_sphere_depth_is_exact_on_the_axis_and_silhouette_matches():
    cam = _cam(65, 49)  # odd size: a pixel centre lies on the optical axis
    scene = Scene((Sphere((0.0, 0.0, 0.0), 1.0, Material(Solid((10.0, 20.0, 30.0)))),), sky=(0.0, 0.0, 0.0))
    v = render(scene, cam)
    assert v.depth[24, 32] == np.float32(3.0)
    assert v.silhouette[24, 32] and not v.silhouette[0, 0]
    assert np.isinf(v.depth[0, 0]) and v.object_id[0, 0] == -1
    # every finite depth backprojects onto the sphere surface
    ys, xs = np.nonzero(np.isfinite(v.depth))
    X = cam.backproject(np.stack([xs, ys], 1).astype(float), v.depth[ys, xs].astype(float))
    np.testing.assert_allclose(np.linalg.norm(X, axis=1), 1.0, atol=1e-5)
    # apparent radius: tangent cone half-angle asin(1/4)
    f = cam.K[0, 0]
    r_px = f * np.tan(np.arcsin(0.25))
    assert abs(v.silhouette[24].sum() - 2 * r_px) <= 2.0
    assert (v.background == 0).all()  # nothing but the black sky behind


def test_box_and_plane_depths_and_occlusion():
    cam = _cam(65, 49)
    scene = Scene((
        Plane((0.0, 2.0, 0.0), (0.0, -1.0, 0.0), Material(Checker(size=0.5))),  # a wall 6 m in front
        Box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), Material(Solid())),
    ))
    v = render(scene, cam)
    assert v.depth[24, 32] == np.float32(3.5)  # front face of the box at y = -0.5
    assert v.depth[0, 0] == np.float32(6.0)  # the wall, z-depth constant on a fronto-parallel plane
    assert v.object_id[24, 32] == 1 and v.object_id[0, 0] == 0
    assert v.silhouette[24, 32] and not v.silhouette[0, 0]
    # the background image shows the wall where the box was
    assert (v.background[24, 32] != v.image[24, 32]).any()
    np.testing.assert_array_equal(v.background[0, 0], v.image[0, 0])


def test_textures_are_view_independent_and_deterministic():
    P = np.random.default_rng(0).uniform(-1, 1, size=(500, 3))
    n1 = fractal_noise(P, 0.1, 4, seed=3)
    np.testing.assert_array_equal(n1, fractal_noise(P, 0.1, 4, seed=3))
    assert not np.allclose(n1, fractal_noise(P, 0.1, 4, seed=4))
    assert 0 <= n1.min() and n1.max() <= 1 and n1.std() > 0.05
    c = ColorNoise(scale=0.1).sample(P)
    assert c.shape == (500, 3) and c.dtype == np.float32
    # checker: parity flips across a cell
    ch = Checker((0.0, 0, 0), (255.0, 255, 255), 1.0).sample(np.array([[0.1, 0.1, 0.1], [1.1, 0.1, 0.1]]))
    assert (ch[0] != ch[1]).all()


def test_gain_scales_colours():
    cam = _cam()
    scene = Scene((Sphere((0.0, 0.0, 0.0), 1.0, Material(Solid((100.0, 100.0, 100.0)))),), ambient=1.0, diffuse=0.0)
    v = render(scene, cam, gain=(1.0, 0.5, 1.2), with_background=False)
    assert tuple(v.image[24, 32]) == (100, 50, 120) and v.background is None


def test_default_arc_rig_geometry():
    rig = default_arc_rig(10, arc_deg=90, radius=2.5, width=64, height=48)
    assert [c.name for c in rig][:2] == ["cam00", "cam01"] and len(rig) == 10
    np.testing.assert_allclose(arc_angles(10, 90)[[0, -1]], [-45, 45])
    target = np.array([0.0, 0.0, 0.5])
    for c in rig:
        d = target - c.center
        np.testing.assert_allclose(np.hypot(d[0], d[1]), 2.5)
        np.testing.assert_allclose(c.axis, d / np.linalg.norm(d), atol=1e-12)
    a = np.degrees(np.arccos(np.clip(rig[0].axis[:2] @ rig[1].axis[:2] / np.linalg.norm(rig[0].axis[:2])
                                     / np.linalg.norm(rig[1].axis[:2]), -1, 1)))
    assert abs(a - 10.0) < 1e-6
    assert len(camera_gains(10)) == 10


def test_default_scene_renders_object_in_every_rig_view():
    scene = default_scene()
    for cam in default_arc_rig(10, width=80, height=60)[::3]:
        v = render(scene, cam)
        assert 0.05 < v.silhouette.mean() < 0.6
        fg = v.silhouette
        assert np.abs(v.image[fg].astype(int) - v.background[fg].astype(int)).sum(axis=1).mean() > 20
        np.testing.assert_array_equal(v.image[~fg], v.background[~fg])


def test_city_scene_has_buildings_above_ground():
    scene = city_scene(seed=1, n_buildings=10)
    cam = Camera.look_at("d", [0, 0, 80], [0, 0, 0], [0, 1, 0], fov_deg=90, width=96, height=72)
    v = render(scene, cam, with_background=False)
    assert np.isfinite(v.depth).all()
    assert v.depth.max() <= 80.0 + 1e-3  # ground at z=0 is the farthest surface
    assert v.silhouette.any() and v.depth[v.silhouette].min() <= 80.0 - 3.0  # roofs at least 3 m up
    assert v.depth[~v.silhouette].min() > 80.0 - 1e-3  # elsewhere: the ground
