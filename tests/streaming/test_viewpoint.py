"""Orbit frames of rigs, virtual cameras from viewpoints, camera paths, viewpoint validation."""
import numpy as np
import pytest
from pydantic import ValidationError

from workers.camera import Camera
from workers.streaming.demo import demo_rig
from workers.streaming.params import BatchRenderParams, Keyframe, Orbit, ViewPose, Viewpoint
from workers.streaming.viewpoint import orbit_frame, path_cameras, rig_up, virtual_camera
from workers.sweep.rig import Rig, RigError
from workers.synth import DEFAULT_TARGET, arc_angles


@pytest.fixture(scope="module")
def rig():
    return demo_rig(10, (320, 240))


def test_orbit_frame_of_the_arc_rig(rig):
    frame = orbit_frame(rig)
    np.testing.assert_allclose(frame.up, [0, 0, 1], atol=1e-9)
    np.testing.assert_allclose(frame.target, DEFAULT_TARGET, atol=1e-6)
    np.testing.assert_allclose(frame.azimuths, arc_angles(10, 90.0), atol=1e-6)
    assert frame.distance == pytest.approx(np.hypot(2.5, 1.3 - 0.5))
    assert frame.elevation == pytest.approx(np.degrees(np.arctan2(0.8, 2.5)))


def test_orbit_at_a_camera_azimuth_is_that_camera(rig):
    frame = orbit_frame(rig)
    cam = rig[7]
    vp = Viewpoint(orbit=Orbit(azimuth=float(frame.azimuths[7])), width=cam.width, height=cam.height, fov=50.0)
    virtual = virtual_camera(vp, frame, (cam.width, cam.height))
    np.testing.assert_allclose(virtual.center, cam.center, atol=1e-6)
    np.testing.assert_allclose(virtual.R, cam.R, atol=1e-6)
    np.testing.assert_allclose(virtual.K, cam.K, atol=1e-6)


def test_look_at_and_pose_viewpoints(rig):
    frame = orbit_frame(rig)
    vp = ViewPose(look_at={"eye": [0, -3, 1], "target": [0, 0, 0.5]}, fov=60)
    cam = virtual_camera(vp, frame, (200, 100))
    np.testing.assert_allclose(cam.center, [0, -3, 1])
    assert cam.project(np.array([[0, 0, 0.5]]))[0][0] == pytest.approx([99.5, 49.5])
    posed = virtual_camera(ViewPose(pose={"R": cam.R.tolist(), "t": cam.t.tolist()}, fov=60), frame, (200, 100))
    np.testing.assert_allclose(posed.P, cam.P, atol=1e-9)
    with pytest.raises(RigError, match="up"):
        virtual_camera(ViewPose(look_at={"eye": [0, 0, 5], "target": [0, 0, 0]}), frame, (64, 48))


def test_rig_up_of_a_parallel_rig_is_the_cameras_up():
    K = np.array([[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]])
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # looking along +y, image up = +z
    rig = Rig(tuple(Camera.from_center(f"c{i}", K, R, [i * 0.1, 0, 0], 64, 48) for i in range(3)))
    np.testing.assert_allclose(rig_up(rig), [0, 0, 1], atol=1e-9)


def test_orbit_path_follows_the_arc(rig):
    frame = orbit_frame(rig)
    keys = [Keyframe(orbit=Orbit(azimuth=-45.0)), Keyframe(orbit=Orbit(azimuth=45.0))]
    cams = path_cameras(keys, None, frame, (64, 48), 10)
    for cam, angle in zip(cams, arc_angles(10, 90.0)):
        np.testing.assert_allclose(cam.center, rig[int(np.argmin(np.abs(arc_angles(10, 90.0) - angle)))].center,
                                   atol=1e-6)
    radii = [np.linalg.norm(c.center - frame.target) for c in cams]
    np.testing.assert_allclose(radii, frame.distance)


def test_keyframes_at_given_parameters():
    rig = demo_rig(4, (64, 48))
    frame = orbit_frame(rig)
    keys = [Keyframe(look_at={"eye": [0, -3, 1], "target": [0, 0, 0.5]}, at=0.0),
            Keyframe(look_at={"eye": [1, -3, 1], "target": [0, 0, 0.5]}, at=0.5),
            Keyframe(look_at={"eye": [1, -2, 1], "target": [0, 0, 0.5]}, at=1.0)]
    cams = path_cameras(keys, [0.0, 0.5, 1.0], frame, (64, 48), 5)
    np.testing.assert_allclose([c.center for c in cams],
                               [[0, -3, 1], [0.5, -3, 1], [1, -3, 1], [1, -2.5, 1], [1, -2, 1]], atol=1e-9)


@pytest.mark.parametrize("message, problem", [
    ({"fov": float("nan")}, "finite"),
    ({"fov": 179}, "less than or equal to 150"),
    ({"orbit": {"azimuth": float("inf")}}, "finite"),
    ({"orbit": {}, "pose": {"R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "t": [0, 0, 0]}}, "not orbit and pose"),
    ({"frame": -1}, "frame"),
    ({"frame": "soon"}, "frame"),
    ({"width": 8}, "width"),
    ({"near": 3, "far": 2}, "near"),
    ({"zoom": 2}, "zoom"),
])
def test_bad_viewpoints_are_refused(message, problem):
    with pytest.raises(ValidationError, match=problem):
        Viewpoint.model_validate(message)


def test_batch_render_params_need_one_path_and_even_sizes():
    with pytest.raises(ValidationError, match="exactly one camera path"):
        BatchRenderParams(recording_id="r")
    with pytest.raises(ValidationError, match="multiple of 2"):
        BatchRenderParams(recording_id="r", orbit={}, width=65)
    with pytest.raises(ValidationError, match="increase"):
        BatchRenderParams(recording_id="r", keyframes=[{"at": 0.5}, {"at": 0.2}])
