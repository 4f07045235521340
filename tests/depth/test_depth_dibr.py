import numpy as np
import pytest

from tests.depth.scene import Scene
from workers.camera import Camera
from workers.depth import dibr
from workers.depth.errors import DepthInputError


def test_single_view_warp_reproduces_the_target_exactly_where_visible():
    scene = Scene()
    tex0, disp0 = scene.render(0)
    tex1, _ = scene.render(1)
    view = dibr.warp_rectified(tex0, disp0, shift=1.0, boundary_width=0)
    visible = scene.visible_from(0, 1)
    np.testing.assert_array_equal(view.valid, visible)
    np.testing.assert_array_equal(view.image[visible], tex1[visible])


def test_boundary_removal_drops_only_background_pixels_beside_disocclusions():
    scene = Scene()
    tex0, disp0 = scene.render(0)
    _, disp1 = scene.render(1)
    plain = dibr.warp_rectified(tex0, disp0, 1.0, boundary_width=0)
    trimmed = dibr.warp_rectified(tex0, disp0, 1.0, boundary_width=2)
    dropped = plain.valid & ~trimmed.valid
    assert dropped.any()
    assert (disp1[dropped] == scene.d_bg).all()
    assert not (trimmed.valid & ~plain.valid).any()


def test_two_views_fill_each_others_disocclusions_exactly():
    scene = Scene()
    (tex0, d0), (tex1, _), (tex2, d2) = scene.render(0), scene.render(1), scene.render(2)
    syn = dibr.synthesize_rectified([tex0, tex2], [d0, d2], [1.0, -1.0], hole_fill="none")
    seen = scene.visible_from(0, 1) | scene.visible_from(2, 1)
    np.testing.assert_array_equal(~syn.holes, seen)
    np.testing.assert_array_equal(syn.image[seen], tex1[seen])
    # everything inside the frame apart from the image borders is seen by one of the two views
    assert not syn.holes[:, scene.d_fg:-scene.d_fg].any()


def test_z_buffer_keeps_the_nearer_surface():
    # pixels 2 (background, d = 1) and 4 (foreground, d = 3) both land on target pixel 1
    disp = np.array([[1, 1, 1, 1, 3, 1, 1, 1]], np.float32)
    tex = np.zeros((1, 8, 3), np.uint8)
    tex[0, 2] = 100
    tex[0, 4] = 255
    view = dibr.warp_rectified(tex, disp, 1.0, crack_fill=False, boundary_width=0)
    assert view.nearness[0, 1] == 3 and (view.image[0, 1] == 255).all()
    assert view.nearness[0, 2] == 1 and (view.image[0, 2] == 0).all()  # pixel 3
    assert not view.valid[0, 3] and not view.valid[0, 7]  # disocclusion and right border


def test_cracks_of_a_stretched_surface_are_filled():
    h, w = 8, 40
    x = np.arange(w, dtype=np.float32)
    disp = np.repeat((20 - 0.4 * x)[None, :], h, 0)  # slanted plane: the warp stretches it by 1.4
    rng = np.random.default_rng(0)
    tex = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    open_ = dibr.warp_rectified(tex, disp, 1.0, crack_fill=False, boundary_width=0)
    closed = dibr.warp_rectified(tex, disp, 1.0, crack_fill=True, boundary_width=0)
    span = slice(1, 35)  # target columns covered by the stretched plane (x - d = 1.4 x - 20 >= 0)
    assert (~open_.valid[:, span]).any()
    assert closed.valid[:, span].all()


def test_hole_filling_copies_the_background_side():
    image = np.zeros((1, 7, 3), np.uint8)
    image[0, :2] = 10  # background on the left
    image[0, 5:] = 250  # foreground on the right
    valid = np.array([[1, 1, 0, 0, 0, 1, 1]], bool)
    near = np.where(valid, np.array([[1, 1, 0, 0, 0, 5, 5]], np.float32), -np.inf).astype(np.float32)
    filled = dibr.fill_holes(dibr.WarpedView(image, valid, near))
    assert (filled[0, 2:5] == 10).all()


def test_general_cameras_match_the_rectified_shift():
    scene = Scene()
    tex0, d0 = scene.render(0)
    tex1, _ = scene.render(1)
    f, baseline = 50.0, 0.1
    K = np.array([[f, 0, 31.5], [0, f, 19.5], [0, 0, 1]])
    cam0 = Camera.from_center("c0", K, np.eye(3), [0.0, 0, 0], scene.width, scene.height)
    cam1 = Camera.from_center("c1", K, np.eye(3), [baseline, 0, 0], scene.width, scene.height)
    depth = (f * baseline / d0).astype(np.float32)
    general = dibr.warp_general(tex0, depth, cam0, cam1, boundary_width=0)
    visible = scene.visible_from(0, 1)
    np.testing.assert_array_equal(general.valid, visible)
    np.testing.assert_array_equal(general.image[visible], tex1[visible])
    _, d1 = scene.render(1)
    np.testing.assert_allclose(general.nearness[visible], (d1 / (f * baseline))[visible], rtol=1e-5)


def test_general_warp_of_a_rotated_camera_round_trips():
    rng = np.random.default_rng(0)
    h, w = 30, 40
    tex = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    depth = np.full((h, w), 4.0, np.float32)
    K = np.array([[40.0, 0, 19.5], [0, 40.0, 14.5], [0, 0, 1]])
    a = Camera.from_center("a", K, np.eye(3), [0, 0, 0], w, h)
    angle = np.radians(3)
    R = np.array([[np.cos(angle), 0, -np.sin(angle)], [0, 1, 0], [np.sin(angle), 0, np.cos(angle)]])
    b = Camera.from_center("b", K, R, [0.05, 0, 0], w, h)
    there = dibr.warp_general(tex, depth, a, b, boundary_width=0)
    assert there.valid.mean() > 0.8
    # every valid target pixel shows the source pixel its ray hits on the plane z = 4
    ys, xs = np.nonzero(there.valid)
    X = b.backproject(np.stack([xs, ys], 1).astype(float), 1 / there.nearness[ys, xs])
    uv, _ = a.project(X)
    assert np.abs(uv[:, 1:] - np.rint(uv[:, 1:])).max() < 1.0  # sanity: projections land in the frame
    assert (uv[:, 0] > -0.5).all() and (uv[:, 0] < w - 0.5).all()


def test_bad_inputs():
    tex = np.zeros((10, 12, 3), np.uint8)
    with pytest.raises(DepthInputError, match="texture is 12x10 but disparity is 11x10"):
        dibr.warp_rectified(tex, np.zeros((10, 11), np.float32), 1.0)
    with pytest.raises(DepthInputError, match="8-bit colour image"):
        dibr.warp_rectified(tex[..., 0], np.zeros((10, 12), np.float32), 1.0)
    with pytest.raises(DepthInputError, match="same number"):
        dibr.synthesize_rectified([tex], [], [1.0])
    with pytest.raises(DepthInputError, match="unknown hole filling"):
        dibr.synthesize_rectified([tex], [np.ones((10, 12), np.float32)], [1.0], hole_fill="blur")
