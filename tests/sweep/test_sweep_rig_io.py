"""Rig importers against hand-written files, and malformed calibration rejected with a message
naming the camera and the field."""
import json

import cv2
import numpy as np
import pytest

from workers.camera import Camera, CameraError, quat_to_rotation, rotation_to_quat
from workers.common.errors import InputError
from workers.sweep.renderer import SweepRenderer
from workers.sweep.rig import Rig, RigError, depth_range_from_box
from workers.sweep.rig_io import (load_colmap_text, load_images, load_middlebury_par, load_middlebury_rectified,
                                  load_opencv_yaml, load_rig, load_uploaded_rig, rig_to_dict, save_rig_json)


def _cam(name, q=(0.9, 0.1, -0.2, 0.3), t=(0.1, -0.2, 2.0), dist=None):
    K = np.array([[500.0, 0, 319.5], [0, 510.0, 239.5], [0, 0, 1]])
    return Camera(name, K, quat_to_rotation(np.array(q)), t, 640, 480, dist)


def test_json_roundtrip(tmp_path):
    rig = Rig((_cam("a"), _cam("b", t=(1, 0, 2), dist=[0.1, 0, 0, 0, 0])), ("a.jpg", "b.jpg"), (0.5, 9.0))
    save_rig_json(rig, tmp_path / "rig.json")
    back = load_rig(tmp_path / "rig.json")
    assert back.names == ["a", "b"] and back.image_files == ("a.jpg", "b.jpg") and back.depth_range == (0.5, 9.0)
    for c0, c1 in zip(rig.cameras, back.cameras):
        np.testing.assert_allclose(c1.P, c0.P)
    np.testing.assert_allclose(back["b"].dist, [0.1, 0, 0, 0, 0])


def test_json_with_center_instead_of_t(tmp_path):
    d = rig_to_dict(Rig((_cam("a"), _cam("b"))))
    for c in d["cameras"]:
        c["center"] = (-np.array(c["R"]).T @ np.array(c["t"])).tolist()
        del c["t"]
    (tmp_path / "r.json").write_text(json.dumps(d))
    np.testing.assert_allclose(load_rig(tmp_path / "r.json")["a"].t, _cam("a").t, atol=1e-12)


def test_colmap_text(tmp_path):
    q = np.array([0.8, 0.2, -0.3, 0.1])
    q /= np.linalg.norm(q)
    (tmp_path / "cameras.txt").write_text(
        "# Camera list\n1 PINHOLE 640 480 500 510 320 240\n2 OPENCV 800 600 700 700 400 300 0.1 -0.02 0.001 0.002\n")
    (tmp_path / "images.txt").write_text(
        "# Image list\n"
        f"1 {q[0]} {q[1]} {q[2]} {q[3]} 0.5 -0.1 3.0 1 left.png\n10.0 20.0 -1\n"
        "2 1 0 0 0 0 0 0 2 right.png\n\n")
    rig = load_rig(tmp_path)
    assert rig.names == ["left.png", "right.png"]
    left = rig["left.png"]
    np.testing.assert_allclose(left.R, quat_to_rotation(q))
    np.testing.assert_allclose(left.t, [0.5, -0.1, 3.0])
    np.testing.assert_allclose(left.K, [[500, 0, 319.5], [0, 510, 239.5], [0, 0, 1]])  # corner -> centre origin
    assert left.dist is None
    right = rig["right.png"]
    np.testing.assert_allclose(right.dist, [0.1, -0.02, 0.001, 0.002])
    assert (right.width, right.height) == (800, 600)


def test_colmap_unsupported_model_names_camera_and_field(tmp_path):
    (tmp_path / "cameras.txt").write_text("7 FISHEYE_WEIRD 640 480 1 2 3\n")
    (tmp_path / "images.txt").write_text("")
    with pytest.raises(RigError, match="camera 7.*'model'"):
        load_colmap_text(tmp_path)


def test_opencv_yaml_with_rodrigues_vector(tmp_path):
    path = str(tmp_path / "rig.yml")
    cams = [_cam("left"), _cam("right", q=(0.7, 0.0, 0.7, 0.1), dist=[0.05, 0.01, 0, 0, 0])]
    fs = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)
    fs.startWriteStruct("cameras", cv2.FileNode_SEQ)
    for i, c in enumerate(cams):
        fs.startWriteStruct("", cv2.FileNode_MAP)
        fs.write("name", c.name)
        fs.write("image_width", c.width)
        fs.write("image_height", c.height)
        fs.write("camera_matrix", c.K)
        if i == 0:
            fs.write("R", c.R)
        else:
            fs.write("rvec", cv2.Rodrigues(c.R)[0])
            fs.write("distortion_coefficients", c.dist.reshape(1, -1))
        fs.write("tvec", c.t.reshape(3, 1))
        fs.endWriteStruct()
    fs.endWriteStruct()
    fs.release()
    rig = load_opencv_yaml(path)
    assert rig.names == ["left", "right"]
    for c0, c1 in zip(cams, rig.cameras):
        np.testing.assert_allclose(c1.P, c0.P, atol=1e-9)
    np.testing.assert_allclose(rig["right"].dist, [0.05, 0.01, 0, 0, 0])


def test_opencv_yaml_missing_field(tmp_path):
    path = tmp_path / "one.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("K", np.eye(3))
    fs.release()
    with pytest.raises(CameraError, match="camera 'one': field 'R'"):
        load_opencv_yaml(path)


@pytest.mark.parametrize("text", ["%YAML:1.0\n---\ncameras:\n  - name: a\n    K: [1, 2\n",
                                  "%YAML:1.0\n---\ncameras:\n  - name: a\n    K: 5\n    R: [1, 2, 3]\n"])
def test_malformed_opencv_yaml_is_a_rig_error(tmp_path, text):
    path = tmp_path / "bad.yml"
    path.write_text(text)
    with pytest.raises(RigError, match="bad.yml is not a valid OpenCV FileStorage file"):
        load_opencv_yaml(path)


def test_middlebury_par(tmp_path):
    c = _cam("x")
    vals = " ".join(f"{v:.17g}" for v in np.concatenate([c.K.ravel(), c.R.ravel(), c.t]))
    (tmp_path / "scene_par.txt").write_text(f"2\nv1.png {vals}\nv2.png {vals}\n")
    cv2.imwrite(str(tmp_path / "v1.png"), np.zeros((48, 64, 3), np.uint8))
    rig = load_rig(tmp_path / "scene_par.txt")
    assert rig.names == ["v1.png", "v2.png"] and (rig["v1.png"].width, rig["v1.png"].height) == (64, 48)
    np.testing.assert_allclose(rig["v2.png"].P, c.P)
    (tmp_path / "bad_par.txt").write_text(f"3\nv1.png {vals}\n")
    with pytest.raises(RigError, match="count"):
        load_middlebury_par(tmp_path / "bad_par.txt", 64, 48)


def test_rectified_middlebury_folder(tmp_path):
    for k in (2, 4, 6):
        cv2.imwrite(str(tmp_path / f"im{k}.png"), np.zeros((30, 40, 3), np.uint8))
    rig = load_middlebury_rectified(tmp_path, baseline=0.1)
    assert rig.names == ["im2", "im4", "im6"] and rig.image_files == ("im2.png", "im4.png", "im6.png")
    np.testing.assert_allclose([c.center[0] for c in rig.cameras], [0.2, 0.4, 0.6])
    assert all(np.allclose(c.R, np.eye(3)) for c in rig.cameras)
    assert load_rig(tmp_path).names == rig.names


def test_malformed_json_calibration_names_camera_and_field(tmp_path):
    d = rig_to_dict(Rig((_cam("a"), _cam("b"))))
    d["cameras"][1]["R"] = [[1, 0, 0], [0, 1, 0], [0, 0.3, 1]]
    (tmp_path / "r.json").write_text(json.dumps(d))
    with pytest.raises(CameraError, match="camera 'b': field 'R': is not orthonormal"):
        load_rig(tmp_path / "r.json")
    d = rig_to_dict(Rig((_cam("a"), _cam("b"))))
    d["cameras"][0]["K"] = [[0, 0, 0], [0, 0, 0], [0, 0, 1]]
    (tmp_path / "r.json").write_text(json.dumps(d))
    with pytest.raises(CameraError, match="camera 'a': field 'K': is singular"):
        load_rig(tmp_path / "r.json")


def test_too_few_cameras_and_duplicates():
    with pytest.raises(RigError, match="rig: field 'cameras': a rig needs at least 2 cameras, got 1"):
        Rig((_cam("a"),))
    with pytest.raises(RigError, match="camera 'a': field 'name'"):
        Rig((_cam("a"), _cam("a")))


def test_mismatched_image_sizes_are_rejected(tmp_path):
    rig = Rig((_cam("a"), _cam("b")))
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((480, 640, 3), np.uint8))
    cv2.imwrite(str(tmp_path / "b.png"), np.zeros((240, 320, 3), np.uint8))
    with pytest.raises(RigError, match="camera 'b': field 'image size': b.png is 320x240, calibration says 640x480"):
        load_images(rig, tmp_path)
    with pytest.raises(RigError, match="camera 'b': field 'image size'"):
        SweepRenderer(rig, [np.zeros((480, 640, 3), np.uint8), np.zeros((240, 320, 3), np.uint8)])
    with pytest.raises(RigError, match="field 'image': 1 given for 2 cameras"):
        SweepRenderer(rig, [np.zeros((480, 640, 3), np.uint8)])


def test_depth_range_from_box_and_focus_point():
    cam = Camera.look_at("v", [0, -5, 0], [0, 0, 0], fov_deg=40)
    near, far = depth_range_from_box(cam, [-1, -1, -1], [1, 1, 1], margin=0.0)
    assert (near, far) == pytest.approx((4.0, 6.0))
    rig = Rig((Camera.look_at("a", [-3, -3, 0], [0, 0, 0]), Camera.look_at("b", [3, -3, 0], [0, 0, 0])))
    np.testing.assert_allclose(rig.focus_point(), [0, 0, 0], atol=1e-9)
    q = rotation_to_quat(rig["a"].R)
    assert q[0] >= 0


def test_uploaded_calibration_files_are_read_by_the_one_entry_point():
    c, c2 = _cam("x"), _cam("x2", t=(0.6, -0.2, 2.0))
    vals = [" ".join(f"{v:.17g}" for v in np.concatenate([k.K.ravel(), k.R.ravel(), k.t])) for k in (c, c2)]
    par = f"2\nv1.png {vals[0]}\nv2.png {vals[1]}\n".encode()
    rig, fmt = load_uploaded_rig([("take_par.txt", par)], 64, 48, units="cm")
    assert fmt == "middlebury" and (rig["v1.png"].width, rig["v1.png"].height) == (64, 48)
    np.testing.assert_allclose(rig["v2.png"].center, c2.center * 0.01)  # the rig comes back in metres
    ours = json.dumps(rig_to_dict(Rig((c, _cam("y", t=(0.5, 0, 2))))))
    rig, fmt = load_uploaded_rig([("rig.json", ours.encode())])
    assert fmt == "json" and rig.names == ["x", "y"]
    for files, size, message in [
        ([("take_par.txt", par)], (None, None), "give the form fields width and height"),
        ([("images.txt", b"")], (None, None), "needs both cameras.txt and images.txt"),
        ([("a.json", b"{}"), ("b.json", b"{}")], (None, None), "only understood as COLMAP text"),
    ]:
        with pytest.raises(ValueError, match=message):
            load_uploaded_rig(files, *size)


def test_uploaded_calibration_errors_name_the_file_never_the_temporary_folder():
    with pytest.raises(ValueError) as info:
        load_uploaded_rig([("mine.json", b"{not json")])
    assert "mine.json" in str(info.value) and "sweepcast-rig-" not in str(info.value) and "/tmp" not in str(info.value)


def test_cameras_at_one_place_are_refused():
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    turned = cv2.Rodrigues(np.array([0.0, 0.3, 0.0]))[0]
    same = (Camera("a", K, np.eye(3), np.zeros(3), 640, 480), Camera("b", K, turned, np.zeros(3), 640, 480))
    with pytest.raises(RigError, match="every camera stands at the same place"):
        Rig(same).require_baseline()
    Rig((same[0], Camera("b", K, np.eye(3), np.array([-0.1, 0, 0]), 640, 480))).require_baseline()  # 10 cm apart
    upload = [("rig.json", json.dumps(rig_to_dict(Rig(same))).encode())]
    with pytest.raises(InputError, match="unusable calibration: .*every camera stands at the same place") as info:
        load_uploaded_rig(upload)  # as the rig route reads it: 422 invalid_rig
    assert (info.value.code, info.value.status) == ("invalid_rig", 422)


def test_uploaded_rigs_over_the_service_limits_and_bad_units_are_refused_with_their_codes():
    rig = json.dumps(rig_to_dict(Rig((_cam("x"), _cam("y", t=(0.5, 0, 2)))))).encode()
    with pytest.raises(InputError, match="the rig has 2 cameras; the limit is 1") as info:
        load_uploaded_rig([("rig.json", rig)], max_cameras=1)
    assert info.value.code == "invalid_rig"
    with pytest.raises(InputError, match="camera x is .*, over the limit of 10 pixels"):
        load_uploaded_rig([("rig.json", rig)], max_pixels=10)
    with pytest.raises(InputError, match="^units: 'furlongs' is not a unit") as info:
        load_uploaded_rig([("rig.json", rig)], units="furlongs")
    assert info.value.code == "invalid_parameters"
