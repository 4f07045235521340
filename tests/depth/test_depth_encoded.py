import cv2
import numpy as np
import pytest
from pydantic import ValidationError

from tests.depth.scene import Scene
from workers.camera import CameraError
from workers.common.images import encode_png
from workers.depth import io
from workers.depth.errors import DepthInputError
from workers.depth.levels import disparity_to_levels
from workers.depth.methods import postprocess
from workers.depth.params import DepthFilterParams, DepthVideoParams, SynthesizeParams
from workers.depth.encoded import filter_depth_bytes, synthesize_bytes


def png(img):
    return encode_png(img)


def test_filter_bytes_matches_the_library():
    rng = np.random.default_rng(0)
    low = rng.integers(0, 256, (10, 12), dtype=np.uint8)
    out = filter_depth_bytes(png(low), {"method": "modified", "scale": 2})
    levels, bits = io.decode_depth(out)
    assert bits == 8
    np.testing.assert_array_equal(levels, postprocess(low, "modified", scale=2))


def test_filter_bytes_sixteen_bit_and_texture_size():
    low = np.full((6, 8), 40000, np.uint16)
    tex = png(np.zeros((12, 16, 3), np.uint8))
    levels, bits = io.decode_depth(filter_depth_bytes(io.encode_depth(low), {"method": "wmf"}, tex))
    assert bits == 16 and levels.shape == (12, 16) and (levels == 40000).all()


def test_filter_bytes_bad_input():
    depth = png(np.zeros((6, 8), np.uint8))
    with pytest.raises(DepthInputError, match="expected a 16-bit depth map"):
        filter_depth_bytes(depth, {"bits": 16})
    with pytest.raises(DepthInputError, match="texture is 10x10 but the depth map is 16x12"):
        filter_depth_bytes(depth, {"method": "wmf", "scale": 2}, png(np.zeros((10, 10, 3), np.uint8)))
    with pytest.raises(ValidationError):
        DepthFilterParams(scale=0)
    with pytest.raises(ValidationError, match="literal_error|Input should be"):
        DepthFilterParams(method="blur")
    with pytest.raises(ValidationError, match="must be odd"):
        DepthFilterParams(window=4)
    with pytest.raises(ValidationError, match="either scale or out_width"):
        DepthFilterParams(scale=2, out_width=10, out_height=10)
    with pytest.raises(ValidationError, match="z_far"):
        DepthVideoParams(width=4, height=4, z_near=5, z_far=2)


def scene_views(p_views=(0, 2)):
    scene = Scene()
    return scene, [scene.render(p) for p in p_views]


def test_synthesize_bytes_disparity_units():
    scene, views = scene_views()
    data = [(png(t), png((d * 4).astype(np.uint8))) for t, d in views]  # level = 4 x disparity
    params = {"depth_units": "disparity", "disparity_scale": 4, "positions": [0, 2], "target_position": 1,
              "hole_fill": "none", "boundary_width": 0}
    image_png, holes_png = synthesize_bytes(data, params)
    image = cv2.imdecode(np.frombuffer(image_png, np.uint8), cv2.IMREAD_COLOR)
    holes = cv2.imdecode(np.frombuffer(holes_png, np.uint8), cv2.IMREAD_UNCHANGED) > 0
    target, _ = scene.render(1)
    seen = scene.visible_from(0, 1) | scene.visible_from(2, 1)
    np.testing.assert_array_equal(~holes, seen)
    np.testing.assert_array_equal(image[seen], target[seen])


def test_synthesize_bytes_inverse_depth_rectified_and_general_agree():
    scene, views = scene_views()
    f, baseline = 40.0, 0.1
    z_near, z_far = f * baseline / scene.d_fg, f * baseline / scene.d_bg
    data = [(png(t), png(disparity_to_levels(d, z_near, z_far, f * baseline))) for t, d in views]
    common = {"z_near": z_near, "z_far": z_far, "hole_fill": "none", "boundary_width": 0}
    rect, _ = synthesize_bytes(data, {**common, "focal_px": f, "positions": [0.0, 2 * baseline],
                                      "target_position": baseline})
    K = [[f, 0, 31.5], [0, f, 19.5], [0, 0, 1]]
    cams = [{"K": K, "t": [0.0, 0, 0]}, {"K": K, "t": [-2 * baseline, 0, 0]}]
    gen, _ = synthesize_bytes(data, {**common, "geometry": "general", "cameras": cams,
                                     "target_camera": {"K": K, "t": [-baseline, 0, 0]}})
    a = cv2.imdecode(np.frombuffer(rect, np.uint8), cv2.IMREAD_COLOR)
    b = cv2.imdecode(np.frombuffer(gen, np.uint8), cv2.IMREAD_COLOR)
    target, _ = scene.render(1)
    seen = scene.visible_from(0, 1) | scene.visible_from(2, 1)
    np.testing.assert_array_equal(a[seen], target[seen])
    np.testing.assert_array_equal(b[seen], target[seen])


def test_synthesize_bad_input():
    scene, views = scene_views()
    data = [(png(t), png((d * 4).astype(np.uint8))) for t, d in views]
    base = {"depth_units": "disparity", "disparity_scale": 4, "positions": [0, 2], "target_position": 1}
    with pytest.raises(DepthInputError, match="got 1 views but the parameters describe 2"):
        synthesize_bytes(data[:1], base)
    small = [(png(views[0][0][:, :10]), data[0][1]), data[1]]
    with pytest.raises(DepthInputError, match="texture is 10x40 but depth map of view 0 is 64x40"):
        synthesize_bytes(small, base)
    with pytest.raises(ValidationError, match="need z_near and z_far"):
        SynthesizeParams(positions=[0], target_position=1, focal_px=10)
    with pytest.raises(ValidationError, match="needs focal_px"):
        SynthesizeParams(positions=[0], target_position=1, z_near=1, z_far=2)
    with pytest.raises(ValidationError, match="general geometry needs cameras"):
        SynthesizeParams(geometry="general", z_near=1, z_far=2)
    bad_cam = {"K": [[0, 0, 1], [0, 0, 1], [0, 0, 1]]}
    with pytest.raises(CameraError, match="field 'K'"):  # a camera of the parameters: 422 invalid_camera
        synthesize_bytes(data[:1], {"geometry": "general", "z_near": 1, "z_far": 2, "cameras": [bad_cam],
                                    "target_camera": bad_cam})
