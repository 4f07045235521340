import cv2
import numpy as np
import pytest

from workers.camera import Camera, CameraError
from workers.depth import io
from workers.common.images import NotAnImage
from workers.depth.errors import DepthInputError


@pytest.mark.parametrize("fmt", ["png", "pgm"])
@pytest.mark.parametrize("dtype,bits", [(np.uint8, 8), (np.uint16, 16)])
def test_depth_image_round_trip(fmt, dtype, bits):
    rng = np.random.default_rng(0)
    depth = rng.integers(0, np.iinfo(dtype).max, (13, 17), dtype=dtype)
    back, got_bits = io.decode_depth(io.encode_depth(depth, fmt))
    assert got_bits == bits
    np.testing.assert_array_equal(back, depth)


def test_declared_bit_depth_is_checked():
    data = io.encode_depth(np.zeros((4, 4), np.uint16))
    with pytest.raises(DepthInputError, match="expected a 8-bit depth map .* 16-bit samples"):
        io.decode_depth(data, bits=8)
    levels, bits = io.decode_depth(io.encode_depth(np.full((4, 4), 1023, np.uint16)), bits=10)
    assert bits == 10 and levels.max() == 1023
    with pytest.raises(DepthInputError, match="above the 10-bit maximum"):
        io.decode_depth(io.encode_depth(np.full((4, 4), 1024, np.uint16)), bits=10)


def test_grey_saved_as_colour_is_accepted_but_colour_is_not():
    grey = np.arange(16, dtype=np.uint8).reshape(4, 4)
    ok, buf = cv2.imencode(".png", cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR))
    np.testing.assert_array_equal(io.decode_depth(buf.tobytes())[0], grey)
    colour = np.zeros((4, 4, 3), np.uint8)
    colour[..., 2] = 9
    ok, buf = cv2.imencode(".png", colour)
    with pytest.raises(DepthInputError, match="single-channel"):
        io.decode_depth(buf.tobytes())
    with pytest.raises(NotAnImage, match="depth map: not a readable image"):
        io.decode_depth(b"hello")


@pytest.mark.parametrize("chroma", ["400", "420"])
@pytest.mark.parametrize("bits", [8, 10, 16])
def test_yuv_round_trip(tmp_path, chroma, bits):
    fmt = io.YuvFormat(7, 5, bits, chroma)  # odd size: 4:2:0 chroma planes round up
    rng = np.random.default_rng(1)
    frames = [rng.integers(0, 2**bits, (5, 7)).astype(np.uint8 if bits == 8 else np.uint16) for _ in range(3)]
    path = tmp_path / "d.yuv"
    io.write_yuv(path, frames, fmt)
    chroma_samples = 0 if chroma == "400" else 2 * 4 * 3
    assert path.stat().st_size == 3 * (35 + chroma_samples) * (1 if bits == 8 else 2)
    np.testing.assert_array_equal(io.read_yuv(path, fmt), np.stack(frames))


def test_yuv_size_must_be_a_whole_number_of_frames(tmp_path):
    fmt = io.YuvFormat(16, 8, 8, "420")
    path = tmp_path / "d.yuv"
    path.write_bytes(bytes(fmt.frame_bytes * 2 + 5))
    with pytest.raises(DepthInputError, match=r"389 bytes, which is not a whole number of 16x8 8-bit 4:2:0 frames \(192"):
        io.read_yuv(path, fmt)
    path.write_bytes(b"")
    with pytest.raises(DepthInputError, match="not a whole number"):
        io.read_yuv(path, fmt)


def test_yuv_levels_above_the_bit_depth_are_refused(tmp_path):
    path = tmp_path / "d.yuv"
    path.write_bytes(np.full(8, 2000, "<u2").tobytes())
    with pytest.raises(DepthInputError, match="frame 0 has level 2000 above the 10-bit maximum"):
        io.read_yuv(path, io.YuvFormat(4, 2, 10))


def test_bad_yuv_format():
    with pytest.raises(DepthInputError, match="chroma format"):
        io.YuvFormat(4, 4, 8, "444")
    with pytest.raises(DepthInputError, match="bit depth"):
        io.YuvFormat(4, 4, 4)


MPEG_TEXT = """param_cam1
1000.0 0.0 640.0
0.0 1000.0 360.0
0.0 0.0 1.0
0
0
1.0 0.0 0.0 -5.0
0.0 1.0 0.0 0.0
0.0 0.0 1.0 0.0

param_cam2
1000.0 0.0 640.0
0.0 1000.0 360.0
0.0 0.0 1.0
0
0
0.0 0.0 1.0 2.0
0.0 1.0 0.0 0.0
-1.0 0.0 0.0 0.0
0 0 0 1
"""


def test_mpeg_camera_file_uses_camera_to_world_extrinsics():
    cams = io.parse_mpeg_cameras(MPEG_TEXT, 1280, 720)
    assert list(cams) == ["param_cam1", "param_cam2"]
    c1, c2 = cams["param_cam1"], cams["param_cam2"]
    np.testing.assert_allclose(c1.center, [-5.0, 0, 0])
    np.testing.assert_allclose(c1.t, [5.0, 0, 0])
    np.testing.assert_allclose(c2.center, [2.0, 0, 0])
    # the file's rotation maps camera axes to world axes: camera +z is R_c2w @ (0, 0, 1) = world +x
    np.testing.assert_allclose(c2.axis, [1.0, 0.0, 0.0], atol=1e-12)
    uv, z = c2.project(np.array([[7.0, 0.0, 0.0]]))  # 5 m in front of cam2
    np.testing.assert_allclose(uv, [[640.0, 360.0]], atol=1e-9)
    assert z[0] == pytest.approx(5.0)


def test_mpeg_camera_round_trip():
    cam = Camera.look_at("v", eye=[1.0, 2.0, 3.0], target=[0.0, 0.0, 10.0], up=[0, -1, 0], width=64, height=48)
    back = io.parse_mpeg_cameras(io.format_mpeg_cameras([cam]), 64, 48)["v"]
    np.testing.assert_allclose(back.K, cam.K, atol=1e-8)
    np.testing.assert_allclose(back.R, cam.R, atol=1e-8)
    np.testing.assert_allclose(back.t, cam.t, atol=1e-8)


def test_bad_mpeg_camera_files():
    with pytest.raises(DepthInputError, match="incomplete"):
        io.parse_mpeg_cameras("cam 1 2 3", 10, 10)
    with pytest.raises(DepthInputError, match="non-numeric"):
        io.parse_mpeg_cameras("cam " + " ".join(["x"] * 23), 10, 10)
    with pytest.raises(DepthInputError, match="no camera"):
        io.parse_mpeg_cameras("  ", 10, 10)
    bad_rotation = MPEG_TEXT.replace("1.0 0.0 0.0 -5.0", "2.0 0.0 0.0 -5.0")
    with pytest.raises(CameraError, match="camera file: .*not orthonormal"):
        io.parse_mpeg_cameras(bad_rotation, 10, 10)
