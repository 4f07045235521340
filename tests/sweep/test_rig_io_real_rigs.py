"""Real rigs: the plain camera-list calibration (CMU Panoptic's layout) with its units and strict
checks, the depth range of a rig without silhouettes from its geometry, and the full sweep without a
hull on distorted cameras."""
import json

import numpy as np
import pytest

from workers.camera import Camera, CameraError
from workers.sweep.renderer import SweepRenderer
from workers.sweep.rig import NEAR_FAR_RATIO, Rig, RigError
from workers.sweep.rig_io import (CAMERA_LIST, is_camera_list, load_rig, metres_per_unit, rig_format,
                                  rig_from_camera_list, rig_to_dict)
from workers.synth import arc_angles, arc_camera, default_arc_rig, default_scene, render, render_views

DIST = [-0.28, 0.09, 0.0005, -0.0004, -0.012]


def ring(n: int = 8, radius: float = 3.0, height: float = 1.2, target=(0.4, -0.3, 0.9), width=1920, height_px=1080,
         dist=None) -> list[Camera]:
    """n cameras evenly round a horizontal circle of ``radius`` about ``target`` (at ``height`` above it),
    all looking at ``target``."""
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n
        eye = np.asarray(target) + [radius * np.cos(a), radius * np.sin(a), height]
        c = Camera.look_at(f"{i:02d}", eye, target, (0, 0, 1), 60.0, width, height_px)
        cams.append(c if dist is None else Camera(c.name, c.K, c.R, c.t, width, height_px, dist))
    return cams


def panoptic_json(cams: list[Camera], cm: bool = True, types=None) -> dict:
    """Cameras in CMU Panoptic's calibration layout (t 3x1, in cm unless ``cm`` is False)."""
    out = []
    for i, c in enumerate(cams):
        out.append({"name": f"00_{i:02d}", "type": (types[i] if types else "hd"), "resolution": [c.width, c.height],
                    "panel": 0, "node": i, "K": c.K.tolist(),
                    "distCoef": (c.dist.tolist() if c.dist is not None else [0.0] * 5), "R": c.R.tolist(),
                    "t": (c.t * (100.0 if cm else 1.0)).reshape(3, 1).tolist()})
    return {"calibDataSource": "synthetic", "cameras": out}


# --- the camera list ------------------------------------------------------------------------------
def test_a_panoptic_camera_list_loads_in_metres_with_its_distortion(tmp_path):
    cams = ring(dist=DIST)
    path = tmp_path / "calibration_171204_pose1.json"
    path.write_text(json.dumps(panoptic_json(cams)))
    assert rig_format(path) == CAMERA_LIST
    rig = load_rig(path)  # default: t in centimetres
    assert rig.names == [f"00_{i:02d}" for i in range(8)]
    for got, want in zip(rig.cameras, cams):
        np.testing.assert_allclose(got.center, want.center, atol=1e-9)  # metres again
        np.testing.assert_allclose(got.K, want.K)
        np.testing.assert_allclose(got.dist, DIST)
        assert (got.width, got.height) == (1920, 1080)
    assert rig.radius() == pytest.approx(np.hypot(3.0, 1.2))
    np.testing.assert_allclose(rig.focus_point(), [0.4, -0.3, 0.9], atol=1e-9)


@pytest.mark.parametrize("units, scale", [("m", 1.0), ("cm", 0.01), ("mm", 0.001), ("0.0254", 0.0254), (0.5, 0.5)])
def test_units_scale_the_translations(tmp_path, units, scale):
    cams = ring(4)
    path = tmp_path / "calib.json"
    path.write_text(json.dumps(panoptic_json(cams, cm=False)))  # t as given: 1 file unit per metre
    rig = load_rig(path, units=units)
    for got, want in zip(rig.cameras, cams):
        np.testing.assert_allclose(got.center, want.center * scale, atol=1e-9)
        np.testing.assert_allclose(got.R, want.R)


def test_units_of_our_json_default_to_metres_and_scale_its_depth_range(tmp_path):
    rig = Rig(tuple(ring(3)), depth_range=(1.0, 9.0))
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(rig_to_dict(rig)))
    assert rig_format(path) == "json" and not is_camera_list(json.loads(path.read_text()))
    np.testing.assert_allclose(load_rig(path).centers(), rig.centers(), atol=1e-12)
    mm = load_rig(path, units="mm")
    np.testing.assert_allclose(mm.centers(), rig.centers() / 1000, atol=1e-12)
    assert mm.depth_range == pytest.approx((0.001, 0.009))


def test_camera_type_keeps_one_kind_and_a_bare_list_loads_too(tmp_path):
    cams = ring(6)
    d = panoptic_json(cams, types=["vga", "hd", "vga", "hd", "kinect-color", "hd"])
    path = tmp_path / "calib.json"
    path.write_text(json.dumps(d))
    assert load_rig(path, camera_type="hd").names == ["00_01", "00_03", "00_05"]
    assert len(load_rig(path)) == 6
    with pytest.raises(RigError, match="no camera of type 'dome' \\(the file has: hd, kinect-color, vga\\)"):
        load_rig(path, camera_type="dome")
    (tmp_path / "bare.json").write_text(json.dumps(d["cameras"]))
    assert load_rig(tmp_path / "bare.json").names == load_rig(path).names
    with pytest.raises(RigError, match="only a plain camera list has camera types"):
        (tmp_path / "ours.json").write_text(json.dumps(rig_to_dict(Rig(tuple(cams)))))
        load_rig(tmp_path / "ours.json", camera_type="hd")


def _broken(field, value, i=1):
    d = panoptic_json(ring(3))
    d["cameras"][i][field] = value
    return d


@pytest.mark.parametrize("d, problem", [
    (_broken("R", [[1, 0, 0], [0, 1, 0], [0, 0.1, 1]]), "camera '00_01': field 'R': is not orthonormal"),
    (_broken("R", [[1, 0, 0], [0, 1, 0], [0, 0, -1]]), "camera '00_01': field 'R': is a reflection"),
    (_broken("R", [[1, 0], [0, 1]]), "camera '00_01': field 'R': must have shape (3, 3)"),
    (_broken("K", [[-1000, 0, 960], [0, 1000, 540], [0, 0, 1]]), "field 'K': focal lengths must be positive"),
    (_broken("K", [[0, 0, 960], [0, 1000, 540], [0, 0, 1]]), "field 'K': is singular"),
    (_broken("K", [[1000, 0, 960], [0, 1000, 540], [0, 0, 2]]), "field 'K': last row must be [0, 0, 1]"),
    (_broken("t", [[1], [2]]), "camera '00_01': field 't': must be 3 numbers"),
    (_broken("t", [[1], [float("nan")], [2]]), "camera '00_01': field 't': contains NaN"),
    (_broken("t", ["a", "b", "c"]), "camera '00_01': field 't': is not numeric"),
    (_broken("distCoef", [0.1, 0.2, 0.3]), "camera '00_01': field 'dist': needs 4, 5, 8, 12, 14 coefficients"),
    (_broken("resolution", [1920]), "camera '00_01': field 'resolution': must be [width, height]"),
    (_broken("resolution", [1920, -1080]), "field 'resolution': must be [width, height], two positive integers"),
    (_broken("resolution", [1920.5, 1080]), "field 'resolution'"),
    (_broken("name", "00_00"), "camera '00_00': field 'name': used by two cameras"),
    ({"cameras": [{"name": "a", "resolution": [4, 4]}, {"name": "b", "resolution": [4, 4]}]},
     "camera 'a': field 'K': missing"),
    ({"cameras": [panoptic_json(ring(2))["cameras"][0], 7]}, "camera '#1': field 'camera': is not an object"),
])
def test_a_camera_list_is_checked_strictly(d, problem):
    with pytest.raises((RigError, CameraError)) as info:
        rig_from_camera_list(d)
    assert problem in str(info.value)


@pytest.mark.parametrize("units, problem", [("furlongs", "is not a unit"), ("-1", "positive"), ("nan", "positive"),
                                            (0, "positive"), ("inf", "positive")])
def test_bad_units_are_refused(units, problem):
    with pytest.raises(RigError, match=problem):
        metres_per_unit(units, CAMERA_LIST)


def test_default_units_per_format():
    assert metres_per_unit(None, CAMERA_LIST) == 0.01 and metres_per_unit(None, "json") == 1.0
    assert metres_per_unit(None, "colmap") == 1.0 and metres_per_unit(" MM ", "json") == 0.001


# --- the depth range of a rig without silhouettes -------------------------------------------------
def test_depth_range_of_a_ring_from_its_geometry():
    target = np.array([0.4, -0.3, 0.9])
    rig = Rig(tuple(ring(8, radius=3.0, height=1.2, target=tuple(target))))
    R = np.hypot(3.0, 1.2)  # every camera's distance from the point all axes meet at
    for d in (R, 2.0, 6.0):  # a virtual camera looking at the focus point from distance d
        v = Camera.look_at("v", target + d * np.array([0.6, -0.8, 0.0]), target, (0, 0, 1), 50, 320, 240)
        assert rig.auto_depth_range(v) == pytest.approx((d - R / 2, d + R))
    home = Camera.look_at("v", target + [0, -3.0, 1.2], target, (0, 0, 1), 50, 320, 240)
    assert rig.auto_depth_range(home) == pytest.approx((R / 2, 2 * R))
    # looking 90 degrees away from the focus point, from 1 m beside it: z_c = 0, the volume ahead is R deep
    side = Camera.look_at("v", target + [0, -1.0, 0], target + [1.0, -1.0, 0], (0, 0, 1), 50, 320, 240)
    assert rig.auto_depth_range(side) == pytest.approx((R / NEAR_FAR_RATIO, R))
    # standing inside the volume, close to the focus point: near is far / 20
    inside = Camera.look_at("v", target + [0, -0.5, 0], target, (0, 0, 1), 50, 320, 240)
    assert rig.auto_depth_range(inside) == pytest.approx(((0.5 + R) / NEAR_FAR_RATIO, 0.5 + R))
    behind = Camera.look_at("v", target + [0, -(R + 1), 0], target + [0, -(R + 2), 0], (0, 0, 1), 50, 320, 240)
    with pytest.raises(RigError, match="working volume is behind the virtual camera"):
        rig.auto_depth_range(behind)
    assert Rig(rig.cameras, depth_range=(1.0, 4.0)).auto_depth_range(home) == (1.0, 4.0)  # a given range wins


def test_depth_range_of_a_dome_from_its_geometry():
    """Cameras on a hemisphere of radius 4 m (three rings and the zenith) about a point 1 m above the
    floor, each looking at it: the focus point is that point, the rig radius 4 m."""
    centre = np.array([1.0, 2.0, 1.0])
    cams = []
    for k, (elev, n) in enumerate([(10, 8), (35, 6), (60, 4), (89.5, 1)]):
        for i in range(n):
            a = 2 * np.pi * (i + 0.5 * k) / n
            e = np.radians(elev)
            eye = centre + 4.0 * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
            up = (0, 1, 0) if elev > 89 else (0, 0, 1)
            cams.append(Camera.look_at(f"d{k}{i}", eye, centre, up, 70, 1920, 1080))
    rig = Rig(tuple(cams))
    np.testing.assert_allclose(rig.focus_point(), centre, atol=1e-9)
    assert rig.radius() == pytest.approx(4.0)
    v = Camera.look_at("v", centre + [0, -5.0, 0], centre, (0, 0, 1), 50, 640, 360)
    assert rig.auto_depth_range(v) == pytest.approx((3.0, 9.0))


def test_the_full_sweep_without_a_hull_finds_the_depth_through_strong_distortion():
    """No silhouettes, no backgrounds, no near/far: the renderer sweeps the rig's working volume
    (1.31..5.25 m here) and finds the objects' true depth on cameras with strong barrel distortion,
    which the synthetic views are rendered through and the renderer undoes at set_frames."""
    size = (192, 144)
    dist = (-0.3, 0.1, 0.0, 0.0, 0.0)
    cams = default_arc_rig(6, arc_deg=75.0, width=size[0], height=size[1], dist=dist)
    scene = default_scene()
    views = render_views(scene, cams, with_background=False)
    renderer = SweepRenderer(Rig(tuple(cams)), [v.image for v in views])
    assert not renderer.has_silhouettes
    a = arc_angles(6, 75.0)
    virtual = arc_camera(float((a[2] + a[3]) / 2), width=size[0], height=size[1], name="virtual")
    out = renderer.render(virtual, planes=64, method="kojima")
    R = np.hypot(2.5, 1.3 - 0.5)  # arc radius and the cameras' height above the focus point
    assert out.visual_hull is False
    assert (out.planes.min(), out.planes.max()) == pytest.approx((R / 2, 2 * R))
    truth = render(scene, virtual)
    objects = truth.silhouette & np.isfinite(out.depth)
    assert objects.sum() > 0.9 * truth.silhouette.sum()  # a depth nearly everywhere on the objects
    err = np.abs(out.depth[objects] - truth.depth[objects])
    step = np.median(truth.depth[objects]) ** 2 * (1 / (R / 2) - 1 / (2 * R)) / 63  # one plane there
    assert np.median(err) < 1.5 * step and np.mean(err < 3 * step) > 0.8
