"""``sweepcast render`` end to end on a generated capture, and its bad-input handling."""
import argparse

import cv2
import numpy as np
import pytest

from workers.sweep.cli import register
from workers.sweep.rig_io import save_rig_json

from .conftest import FAR, NEAR


def _parser():
    p = argparse.ArgumentParser(prog="sweepcast")
    register(p.add_subparsers(dest="cmd", required=True))
    return p


@pytest.fixture()
def capture_dir(tmp_path, capture):
    _, rig, views = capture
    (tmp_path / "img").mkdir()
    (tmp_path / "bg").mkdir()
    for cam, v in zip(rig.cameras, views):
        cv2.imwrite(str(tmp_path / "img" / f"{cam.name}.png"), v.image)
        cv2.imwrite(str(tmp_path / "bg" / f"{cam.name}.png"), v.background)
    save_rig_json(rig, tmp_path / "rig.json")
    return tmp_path


def test_render_writes_view_depth_and_regions(capture_dir, capsys):
    d = capture_dir
    args = _parser().parse_args([
        "render", "--rig", str(d / "rig.json"), "--images", str(d / "img"), "--backgrounds", str(d / "bg"),
        "--pose", "cam02:cam03:0.4", "--method", "kojima", "--planes", "24", "--near", str(NEAR), "--far", str(FAR),
        "--out", str(d / "out" / "view.png"), "--depth-out", str(d / "depth.npy"), "--regions-out", str(d / "reg.png"),
    ])
    assert args.func(args) == 0
    view = cv2.imread(str(d / "out" / "view.png"))
    depth = np.load(d / "depth.npy")
    regions = cv2.imread(str(d / "reg.png"))
    assert view.shape == (120, 160, 3) and depth.shape == (120, 160) and regions.shape == (120, 160, 3)
    found = np.isfinite(depth)
    assert 0.05 < found.mean() < 0.9 and (NEAR <= depth[found]).all() and (depth[found] <= FAR).all()
    assert (view[~found] == 0).all()
    assert "sweep" in capsys.readouterr().out


def test_render_lookat_pose_with_size(capture_dir):
    d = capture_dir
    args = _parser().parse_args([
        "render", "--rig", str(d / "rig.json"), "--images", str(d / "img"), "--backgrounds", str(d / "bg"),
        "--pose", "lookat:0.3,-2.5,1.3:0,0,0.5", "--size", "80x60", "--planes", "16", "--near", str(NEAR),
        "--far", str(FAR), "--out", str(d / "v.png"), "--depth-out", str(d / "d.png"),
    ])
    assert args.func(args) == 0
    assert cv2.imread(str(d / "v.png")).shape == (60, 80, 3) and cv2.imread(str(d / "d.png")) is not None


def test_render_with_k_camera_blending_matches_the_library(capture_dir, capture):
    """``--method kojima_k`` renders what SweepRenderer renders with that method (D_bnd derived and given)."""
    from workers.sweep.renderer import SweepRenderer
    from workers.sweep.rig_io import load_images, load_rig
    from workers.sweep.virtual import parse_pose

    d = capture_dir
    for extra in ([], ["--d-bnd", "0.1"]):
        args = _parser().parse_args([
            "render", "--rig", str(d / "rig.json"), "--images", str(d / "img"), "--backgrounds", str(d / "bg"),
            "--pose", "cam02:cam03:0.4", "--method", "kojima_k", "--planes", "16", "--near", str(NEAR), "--far",
            str(FAR), "--out", str(d / "k.png"), "--regions-out", str(d / "k_reg.png"), *extra])
        assert args.func(args) == 0
        rig = load_rig(str(d / "rig.json"))
        r = SweepRenderer(rig, load_images(rig, str(d / "img")), backgrounds=load_images(rig, str(d / "bg")))
        want = r.render(parse_pose("cam02:cam03:0.4", rig), method="kojima_k", planes=16, near=NEAR, far=FAR,
                        d_bnd=float(extra[1]) if extra else None)
        np.testing.assert_array_equal(cv2.imread(str(d / "k.png")), want.image)
        if extra:  # D_bnd 0.1 is wide for 15-degree spacing: three or more cameras somewhere, drawn red
            assert (want.regions >= 3).any()
            assert (cv2.imread(str(d / "k_reg.png"))[want.regions >= 3] == (0, 0, 230)).all()


@pytest.mark.parametrize("change,needle", [
    (["--pose", "nosuchcam"], "camera 'nosuchcam': field 'name'"),
    (["--pose", "cam01:cam02:abc"], "not a number"),
    (["--size", "big"], "WxH"),
    (["--images", "/nonexistent"], "field 'image'"),
    (["--d-bnd", "-1"], "d_bnd"),
    (["--near", "3", "--far", "2"], "near/far"),
])
def test_bad_input_is_one_line_and_exit_code_2(capture_dir, capsys, change, needle):
    d = capture_dir
    argv = ["render", "--rig", str(d / "rig.json"), "--images", str(d / "img"), "--pose", "cam02",
            "--planes", "8", "--out", str(d / "v.png")]
    for i in range(0, len(change), 2):
        if change[i] in argv:
            argv[argv.index(change[i]) + 1] = change[i + 1]
        else:
            argv += change[i:i + 2]
    args = _parser().parse_args(argv)
    assert args.func(args) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "\n" not in err and "Traceback" not in err


def test_wrong_image_size_names_the_camera(capture_dir, capsys):
    d = capture_dir
    cv2.imwrite(str(d / "img" / "cam04.png"), np.zeros((10, 10, 3), np.uint8))
    args = _parser().parse_args(["render", "--rig", str(d / "rig.json"), "--images", str(d / "img"), "--pose", "cam02",
                                 "--out", str(d / "v.png")])
    assert args.func(args) == 2
    assert "camera 'cam04': field 'image size'" in capsys.readouterr().err
