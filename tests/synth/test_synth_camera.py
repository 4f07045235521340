"""workers.camera: projection against hand-computed answers, validation, interpolation."""
import numpy as np
import pytest

from workers.camera import Camera, CameraError, interpolate, quat_to_rotation, rotation_to_quat, slerp


def _K(f=100.0, cx=50.0, cy=40.0):
    return np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])


def test_project_known_answer():
    cam = Camera("c", _K(), np.eye(3), [0, 0, 2.0], 101, 81)  # centre at z = -2
    uv, z = cam.project(np.array([[0.0, 0, 0], [1.0, -0.5, 2.0]]))
    np.testing.assert_allclose(z, [2.0, 4.0])
    np.testing.assert_allclose(uv, [[50, 40], [50 + 100 * 1 / 4, 40 - 100 * 0.5 / 4]])
    np.testing.assert_allclose(cam.center, [0, 0, -2])
    np.testing.assert_allclose(cam.axis, [0, 0, 1])


def test_point_behind_camera_is_nan():
    cam = Camera("c", _K(), np.eye(3), [0, 0, 0.0], 101, 81)
    uv, z = cam.project(np.array([[0.0, 0, -1]]))
    assert z[0] == -1 and np.isnan(uv).all()


def test_backproject_roundtrip_with_and_without_distortion():
    rng = np.random.default_rng(0)
    R = quat_to_rotation(rng.normal(size=4))
    for dist in (None, [0.1, -0.05, 0.001, 0.002, 0.01]):
        cam = Camera.from_center("c", _K(300, 160, 120), R, [0.3, -0.2, 0.5], 320, 240, dist)
        uv = rng.uniform([20, 20], [300, 220], size=(50, 2))
        depth = rng.uniform(1, 5, size=50)
        X = cam.backproject(uv, depth)
        uv2, z2 = cam.project(X)
        np.testing.assert_allclose(z2, depth, rtol=1e-9)
        np.testing.assert_allclose(uv2, uv, atol=1e-4)


def test_look_at_orientation():
    cam = Camera.look_at("v", eye=[0, -5, 1], target=[0, 0, 1], up=[0, 0, 1], fov_deg=90, width=200, height=100)
    np.testing.assert_allclose(cam.axis, [0, 1, 0], atol=1e-12)
    assert cam.K[0, 0] == pytest.approx(100.0)  # 90 deg across 200 px
    uv, _ = cam.project(np.array([[1.0, 0, 1], [0, 0, 2]]))
    assert uv[0, 0] > cam.K[0, 2]  # +x (right of the line of sight) appears right
    assert uv[1, 1] < cam.K[1, 2]  # up appears up (smaller v)


def test_scaled_keeps_pixel_centre_convention():
    cam = Camera("c", _K(100, 49.5, 39.5), np.eye(3), [0, 0, 0.0], 100, 80)
    half = cam.scaled(0.5)
    assert (half.width, half.height) == (50, 40)
    np.testing.assert_allclose(half.K, [[50, 0, 24.5], [0, 50, 19.5], [0, 0, 1]])


def test_quaternion_roundtrip_and_slerp_midpoint():
    rng = np.random.default_rng(1)
    for _ in range(20):
        R = quat_to_rotation(rng.normal(size=4))
        np.testing.assert_allclose(quat_to_rotation(rotation_to_quat(R)), R, atol=1e-12)
    qz90 = np.array([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])
    mid = quat_to_rotation(slerp(np.array([1.0, 0, 0, 0]), qz90, 0.5))
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    np.testing.assert_allclose(mid, [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-12)


def test_interpolate_endpoints_and_midpoint():
    a = Camera.look_at("a", [2, 0, 0], [0, 0, 0], fov_deg=60)
    b = Camera.look_at("b", [0, 2, 0], [0, 0, 0], fov_deg=40)
    for s, ref in ((0.0, a), (1.0, b)):
        c = interpolate(a, b, s)
        np.testing.assert_allclose(c.R, ref.R, atol=1e-9)
        np.testing.assert_allclose(c.center, ref.center, atol=1e-9)
        np.testing.assert_allclose(c.K, ref.K, atol=1e-9)
    m = interpolate(a, b, 0.5)
    np.testing.assert_allclose(m.center, [1, 1, 0], atol=1e-12)
    np.testing.assert_allclose(m.axis, -np.array([1, 1, 0]) / np.sqrt(2), atol=1e-9)  # still looks at the origin


@pytest.mark.parametrize("field,kwargs,needle", [
    ("R", {"R": [[1, 0, 0], [0, 1, 0.2], [0, 0, 1]]}, "orthonormal"),
    ("R", {"R": np.diag([1.0, 1, -1])}, "reflection"),
    ("K", {"K": np.zeros((3, 3)) + np.diag([0, 0, 1.0])}, "singular"),
    ("K", {"K": [[100, 0, 50], [0, 100, 40]]}, "shape"),
    ("t", {"t": [0, np.nan, 1]}, "NaN"),
    ("width", {"width": 0}, "positive"),
    ("height", {"height": 12.5}, "integer"),
    ("dist", {"dist": [0.1, 0.2, 0.3]}, "coefficients"),
])
def test_malformed_calibration_names_camera_and_field(field, kwargs, needle):
    args = {"name": "left-7", "K": _K(), "R": np.eye(3), "t": np.zeros(3), "width": 100, "height": 80}
    args.update(kwargs)
    with pytest.raises(CameraError) as err:
        Camera(**args)
    assert err.value.camera == "left-7" and err.value.field == field
    assert "left-7" in str(err.value) and repr(field) in str(err.value) and needle in str(err.value)
    assert isinstance(err.value, ValueError)


def test_dict_roundtrip_and_missing_field():
    cam = Camera("c", _K(), quat_to_rotation([0.9, 0.1, 0.2, 0.3]), [1, 2, 3], 100, 80, [0.1, 0, 0, 0])
    back = Camera.from_dict(cam.to_dict())
    np.testing.assert_allclose(back.P, cam.P)
    np.testing.assert_allclose(back.dist, cam.dist)
    d = cam.to_dict()
    del d["K"]
    with pytest.raises(CameraError, match="'K'"):
        Camera.from_dict(d)
