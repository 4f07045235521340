"""Plane-induced homographies and the kernel's projection against known answers."""
import numpy as np

from workers.camera import Camera
from workers.sweep.reference import plane_homographies
from workers.sweep.renderer import SweepRenderer
from workers.sweep.rig_io import rectified_rig


def _K(f=100.0, cx=79.5, cy=59.5):
    return np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])


def test_rectified_homography_is_a_horizontal_shift_by_the_disparity():
    rig = rectified_rig(["a.png", "b.png"], 160, 120, positions=[0, 1], focal=100.0, baseline=0.2)
    virtual = rig[0]
    H = plane_homographies(list(rig.cameras), virtual, depth=4.0)
    # camera b is 0.2 to the right: a point at depth 4 moves left by f b / z = 5 px
    p = H[1] @ np.array([30.0, 40.0, 1.0])
    np.testing.assert_allclose(p[:2] / p[2], [25.0, 40.0])
    np.testing.assert_allclose(H[0] / H[0][2, 2], np.eye(3), atol=1e-12)


def test_homography_maps_to_the_projection_of_the_plane_point():
    rng = np.random.default_rng(3)
    virtual = Camera.look_at("v", [0.3, -3, 1.0], [0, 0, 0.5], fov_deg=50, width=160, height=120)
    cams = [Camera.look_at(f"c{i}", [np.sin(a) * 3, -np.cos(a) * 3, 1.2], [0, 0, 0.5], fov_deg=45,
                           width=200, height=150) for i, a in enumerate(np.radians([-30, 10, 40]))]
    uv = rng.uniform([0, 0], [159, 119], size=(20, 2))
    for z in (1.5, 2.7, 6.0):
        X = virtual.backproject(uv, z)
        Hs = plane_homographies(cams, virtual, z)
        for H, cam in zip(Hs, cams):
            p = np.hstack([uv, np.ones((20, 1))]) @ H.T
            want, _ = cam.project(X)
            np.testing.assert_allclose(p[:, :2] / p[:, 2:], want, atol=1e-8)


def test_renderer_geometry_matches_homographies():
    cams = [Camera("a", _K(), np.eye(3), [0, 0, 0.0], 160, 120),
            Camera.from_center("b", _K(90), np.eye(3), [0.5, 0.1, 0.0], 160, 120)]
    images = [np.zeros((120, 160, 3), np.uint8)] * 2
    r = SweepRenderer(cams, images)
    virtual = Camera.from_center("v", _K(120, 60, 50), np.eye(3), [0.2, 0, -0.3], 120, 100)
    Q, B, _ = r.geometry(virtual)
    z = 3.0
    Hs = plane_homographies(cams, virtual, z)
    for i in range(2):
        np.testing.assert_allclose((Q[i] + np.outer(B[i], [0, 0, 1]) / z), Hs[i], atol=1e-12)
