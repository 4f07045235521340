"""The first-run demo: its photographic studio, the lens model of the synthetic cameras, the
recording built by casting only what the moving ball changes, and the cache that renders it once."""
import dataclasses
import json

import numpy as np
import pytest

from app.stored_rigs import rig_json_bytes
from workers.camera import Camera
from workers.streaming import demo as demo_module
from workers.streaming.demo import (DEMO_SIZE, build_demo_recording, demo_recording, demo_recording_key, demo_rig,
                                    demo_scene)
from workers.streaming.recording import RecordingArchive
from workers.sweep.rig_io import rig_from_dict
from workers.synth import (BoxPicture, Material, Planks, Scene, Sphere, SpherePicture, render, render_views,
                           sample_image, sample_photo, studio_scene)


def test_the_demo_rig_and_studio():
    rig = demo_rig()
    assert len(rig) == 10 and {(c.width, c.height) for c in rig.cameras} == {DEMO_SIZE} == {(640, 480)}
    scene = studio_scene()
    textures = [type(o.material.texture) for o in scene.objects]
    assert BoxPicture in textures and SpherePicture in textures and Planks in textures
    assert scene.shadows > 0
    china = sample_photo("china.jpg")
    assert china.shape == (427, 640, 3) and china.dtype == np.uint8


def test_bilinear_picture_sampling_hits_pixel_centres():
    img = np.arange(4 * 6 * 3, dtype=np.float32).reshape(4, 6, 3)
    u = (np.array([0, 5, 2]) + 0.5) / 6
    v = (np.array([0, 3, 1]) + 0.5) / 4
    np.testing.assert_allclose(sample_image(img, u, v), img[[0, 3, 1], [0, 5, 2]])
    mid = sample_image(img, np.array([1.0 / 6]), np.array([0.5 / 4]))  # half-way between pixels 0 and 1
    np.testing.assert_allclose(mid[0], (img[0, 0] + img[0, 1]) / 2)
    np.testing.assert_allclose(sample_image(img, u + 1.0, v - 2.0), img[[0, 3, 1], [0, 5, 2]])  # repeats


def test_a_distorted_camera_sees_points_where_its_lens_puts_them():
    """A small sphere off-axis rendered by a camera with strong barrel distortion appears where
    Camera.project (OpenCV's model) puts its centre, not where the pinhole would."""
    ball = Sphere((1.9, 0.0, 3.0), 0.06, Material())
    pinhole = Camera.look_at("c", (0, 0, 0), (0, 0, 1), (0, -1, 0), 70, 400, 300)
    lens = Camera(pinhole.name, pinhole.K, pinhole.R, pinhole.t, 400, 300, (-0.3, 0.1, 0.0, 0.0, 0.0))
    view = render(Scene((ball,)), lens, with_background=False)
    ys, xs = np.nonzero(view.silhouette)
    found = np.array([xs.mean(), ys.mean()])
    want, _ = lens.project(np.array([ball.center]))
    ideal, _ = pinhole.project(np.array([ball.center]))
    assert np.linalg.norm(found - want[0]) < 1.0 and np.linalg.norm(ideal[0] - want[0]) > 15


def test_the_demo_recording_equals_full_renders_of_every_frame(tmp_path):
    rig = demo_rig(3, (96, 72))
    info = build_demo_recording(rig, tmp_path / "demo.zip", 4, 6.0)
    assert (info.frames, info.fps, info.background) == (4, 6.0, "given")
    archive = RecordingArchive(tmp_path / "demo.zip")
    for f in range(4):
        full = render_views(demo_scene(f / 4), list(rig.cameras), with_background=(f == 0))
        for got, want in zip(archive.frame_set(f), full):
            np.testing.assert_array_equal(got, want.image)
        if f == 0:
            for got, want in zip(archive.backgrounds(), full):
                np.testing.assert_array_equal(got, want.background)
    moved = [np.abs(archive.frame_set(f)[1].astype(int) - archive.frame_set(0)[1]).max() for f in range(1, 4)]
    assert min(moved) > 50  # the ball moved between frames


@pytest.mark.parametrize("phase", [0.0, 0.5])
def test_the_ball_casts_a_soft_shadow_on_the_stage(phase):
    """The point of the stage behind the ball's centre, seen from the light, is darker with the ball
    there than without it, and no darker than the ambient light alone leaves it."""
    scene = demo_scene(phase)
    ball = next(o for o in scene.objects if isinstance(o, Sphere) and o.radius < 0.2)
    light = np.asarray(scene.light_dir) / np.linalg.norm(scene.light_dir)
    top = 0.08  # the stage's top face
    t = (ball.center[2] - top) / light[2]
    ground = np.asarray(ball.center) - t * light  # where the ray to the light through the ball's centre meets the stage
    cam = Camera.look_at("c", ground + [0.0, 0.4, 1.0], ground, (0, 0, 1), 30, 64, 48)  # from behind: the ball aside
    with_ball = render(scene, cam, with_background=False)
    without = render(dataclasses.replace(scene, objects=tuple(o for o in scene.objects if o is not ball)), cam,
                     with_background=False)
    assert with_ball.object_id[24, 32] == without.object_id[24, 32] == 1  # the stage, seen past the ball
    shaded, lit = with_ball.image[24, 32].astype(float).sum(), without.image[24, 32].astype(float).sum()
    ambient_share = scene.ambient / (scene.ambient + scene.diffuse * light[2])  # the top face, n = z
    assert shaded < 0.7 * lit and shaded > 0.9 * ambient_share * lit


def _no_render(*args, **kwargs):
    raise AssertionError("rendered although the cache holds the recording")


def test_the_demo_recording_is_rendered_once_then_copied_from_the_cache(tmp_path, monkeypatch):
    rig, cache = demo_rig(2, (32, 24)), tmp_path / "cache"
    first = demo_recording(rig, tmp_path / "a.zip", 2, 6.0, cache)
    assert [p.name for p in cache.iterdir()] == [f"{demo_recording_key(rig, 2, 6.0)}.zip"]
    monkeypatch.setattr(demo_module, "build_demo_recording", _no_render)
    steps = []
    again = demo_recording(rig, tmp_path / "b.zip", 2, 6.0, cache, lambda f, s: steps.append((f, s)))
    assert again == first and steps == [(1.0, "demo recording copied from the cache")]
    assert (tmp_path / "a.zip").read_bytes() == (tmp_path / "b.zip").read_bytes()


def test_the_cache_key_follows_rig_length_and_rate_and_survives_the_stored_rig_json():
    """The key the warm-up renders under is the one the demo job looks up: the job reads the rig back from
    the JSON the service stored."""
    rig = demo_rig()
    key = demo_recording_key(rig, 12, 6.0)
    assert demo_recording_key(rig_from_dict(json.loads(rig_json_bytes(rig))), 12, 6.0) == key
    assert len({key, demo_recording_key(rig, 13, 6.0), demo_recording_key(rig, 12, 5.0),
                demo_recording_key(demo_rig(9), 12, 6.0)}) == 4


def test_a_damaged_cached_recording_is_rendered_again_and_replaced(tmp_path):
    rig, cache = demo_rig(2, (32, 24)), tmp_path / "cache"
    cache.mkdir()
    cached = cache / f"{demo_recording_key(rig, 2, 6.0)}.zip"
    cached.write_bytes(b"PK\x03\x04 half a zip")
    (cache / "an-older-renderers-key.zip").write_bytes(b"old")
    info = demo_recording(rig, tmp_path / "a.zip", 2, 6.0, cache)
    assert info.frames == 2 and RecordingArchive(tmp_path / "a.zip").info == info
    assert sorted(p.name for p in cache.iterdir()) == [cached.name]  # replaced; the older one deleted
    assert cached.read_bytes() == (tmp_path / "a.zip").read_bytes()


def test_an_unwritable_cache_only_costs_the_copy(tmp_path):
    rig, blocked = demo_rig(2, (32, 24)), tmp_path / "a-file-not-a-folder"
    blocked.write_bytes(b"")
    info = demo_recording(rig, tmp_path / "a.zip", 2, 6.0, blocked)
    assert info.frames == 2 and RecordingArchive(tmp_path / "a.zip").info == info


def test_the_cached_recording_is_readable_by_others_as_any_new_file(tmp_path):
    rig, cache = demo_rig(2, (32, 24)), tmp_path / "cache"
    demo_recording(rig, tmp_path / "a.zip", 2, 6.0, cache)
    (cached,) = cache.iterdir()
    assert cached.stat().st_mode & 0o777 == (tmp_path / "a.zip").stat().st_mode & 0o777


def test_a_recording_the_wheel_carries_is_copied_when_the_cache_has_none(tmp_path, monkeypatch):
    rig, shipped = demo_rig(2, (32, 24)), tmp_path / "shipped"
    made = demo_recording(rig, tmp_path / "made.zip", 2, 6.0, shipped)  # as packaging/build-wheel.sh's warm-up does
    shipped.chmod(0o555)  # an install may be read-only
    monkeypatch.setattr(demo_module, "SHIPPED_DEMO", shipped)
    monkeypatch.setattr(demo_module, "build_demo_recording", _no_render)
    cache = tmp_path / "cache"
    kept = demo_module.cached_demo_recording(cache, rig, 2, 6.0)
    assert kept is not None and kept[0].parent == shipped and kept[1] == made
    assert demo_recording(rig, tmp_path / "a.zip", 2, 6.0, cache) == made
    assert (tmp_path / "a.zip").read_bytes() == (tmp_path / "made.zip").read_bytes()
    assert demo_module.cached_demo_recording(cache, demo_rig(3, (32, 24)), 2, 6.0) is None  # another rig: rendered
