import argparse

import cv2
import numpy as np
import pytest

from tests.depth.scene import Scene
from workers.camera import Camera
from workers.depth import io
from workers.depth.cli import register
from workers.depth.levels import disparity_to_levels
from workers.depth.methods import postprocess


def run(argv):
    parser = argparse.ArgumentParser(prog="sweepcast")
    register(parser.add_subparsers(dest="verb", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def test_filter_png_to_pgm(tmp_path):
    rng = np.random.default_rng(0)
    low = rng.integers(0, 256, (10, 12), dtype=np.uint8)
    io.write_depth(tmp_path / "in.png", low)
    assert run(["depth", "filter", str(tmp_path / "in.png"), str(tmp_path / "out.pgm"),
                "--method", "dilation", "--scale", "2", "--upsampler", "bilinear"]) == 0
    out, _ = io.read_depth(tmp_path / "out.pgm")
    np.testing.assert_array_equal(out, postprocess(low, "dilation", scale=2, upsampler="bilinear"))


def test_filter_yuv_sequence(tmp_path, capsys):
    fmt = io.YuvFormat(8, 6, 8, "420")
    frames = [np.full((6, 8), v, np.uint8) for v in (10, 20)]
    io.write_yuv(tmp_path / "in.yuv", frames, fmt)
    assert run(["depth", "filter", str(tmp_path / "in.yuv"), str(tmp_path / "out.yuv"), "--width", "8",
                "--height", "6", "--chroma", "420", "--size", "16x12"]) == 0
    out = io.read_yuv(tmp_path / "out.yuv", io.YuvFormat(16, 12, 8, "420"))
    assert out.shape == (2, 12, 16) and (out[1] == 20).all()
    assert (tmp_path / "out.report.json").exists()
    assert "2 frames" in capsys.readouterr().out


def test_synthesize_rectified_and_with_an_mpeg_camera_file(tmp_path):
    scene = Scene()
    paths = []
    for p in (0, 2):
        tex, disp = scene.render(p)
        cv2.imwrite(str(tmp_path / f"t{p}.png"), tex)
        io.write_depth(tmp_path / f"d{p}.png", (disp * 4).astype(np.uint8))
        paths += ["--view", str(tmp_path / f"t{p}.png"), str(tmp_path / f"d{p}.png")]
    assert run(["depth", "synthesize", *paths, "--depth-units", "disparity", "--disparity-scale", "4",
                "--positions", "0", "2", "--target-position", "1", "--out", str(tmp_path / "v.png"),
                "--holes", str(tmp_path / "h.png")]) == 0
    target, _ = scene.render(1)
    seen = scene.visible_from(0, 1) | scene.visible_from(2, 1)
    assert (cv2.imread(str(tmp_path / "v.png"))[seen] == target[seen]).mean() > 0.99

    f, b = 40.0, 0.1
    K = np.array([[f, 0, 31.5], [0, f, 19.5], [0, 0, 1]])
    cams = [Camera.from_center(n, K, np.eye(3), [x, 0, 0], 64, 40) for n, x in (("c0", 0), ("c1", b), ("c2", 2 * b))]
    (tmp_path / "cams.txt").write_text(io.format_mpeg_cameras(cams))
    z_near, z_far = f * b / scene.d_fg, f * b / scene.d_bg
    for p in (0, 2):
        _, disp = scene.render(p)
        io.write_depth(tmp_path / f"d{p}.png", disparity_to_levels(disp, z_near, z_far, f * b))
    assert run(["depth", "synthesize", *paths, "--cameras", str(tmp_path / "cams.txt"), "--names", "c0", "c2",
                "--target", "c1", "--z-near", str(z_near), "--z-far", str(z_far), "--boundary-width", "0",
                "--out", str(tmp_path / "g.png")]) == 0
    got = cv2.imread(str(tmp_path / "g.png"))
    np.testing.assert_array_equal(got[seen], target[seen])


@pytest.mark.parametrize("argv,message", [
    (["depth", "filter", "{d}/missing.png", "{d}/o.png"], "No such file"),
    (["depth", "filter", "{d}/in.png", "{d}/o.png", "--method", "blur"], "method: Input should be"),
    (["depth", "filter", "{d}/in.png", "{d}/o.png", "--scale", "0"], "scale: Input should be greater than 0"),
    (["depth", "filter", "{d}/in.png", "{d}/o.png", "--bits", "16"], "expected a 16-bit depth map"),
    (["depth", "filter", "{d}/in.yuv", "{d}/o.yuv", "--width", "5", "--height", "5"], "not a whole number"),
    (["depth", "filter", "{d}/in.yuv", "{d}/o.yuv"], "needs --width and --height"),
])
def test_bad_input_prints_one_line_and_exits_2(tmp_path, capsys, argv, message):
    io.write_depth(tmp_path / "in.png", np.zeros((4, 4), np.uint8))
    (tmp_path / "in.yuv").write_bytes(bytes(7))
    code = run([a.format(d=tmp_path) for a in argv])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("error: ") and message in err and err.count("\n") == 1
