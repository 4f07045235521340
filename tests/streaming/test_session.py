"""Sessions without Ray: rendering a recording or a live stream into JPEG frames with headers."""
import cv2
import numpy as np
import pytest

from harness.takes import jpeg
from workers.streaming.background import BackgroundModel
from workers.streaming.images import ImageError, decode_image, decode_reduced, reduced_size
from workers.streaming.params import Orbit, Viewpoint
from workers.streaming.recording import ArchiveWriter, RecordingArchive
from workers.streaming.session import LiveSession, RecordingSession, SessionLimits, ViewError
from workers.streaming.viewpoint import orbit_frame

PLANES = 32


@pytest.fixture(scope="module")
def archive(take, tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "rec.zip"
    writer = ArchiveWriter(path, take.rig, 5.0)
    for frame in take.frames:
        for c, image in enumerate(frame):
            writer.add(c, image)
    for c, bg in enumerate(take.backgrounds):
        writer.set_background(c, bg)
    writer.finish("given")
    return RecordingArchive(path)


@pytest.fixture
def session(take, archive):
    return RecordingSession(take.rig, archive, SessionLimits(max_pixels=200 * 200, max_planes=64))


def decode(data):
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)


def at_camera(take, c, **fields):
    """A viewpoint at rig camera ``c``'s place; one quality level throughout ("fast" unless given: "auto" would
    change it after the first frames, and the depth with it)."""
    az = float(orbit_frame(take.rig).azimuths[c])
    cam = take.rig[c]
    fields.setdefault("render_quality", "fast")
    return Viewpoint(orbit=Orbit(azimuth=az), width=cam.width, height=cam.height, fov=50.0, planes=PLANES,
                     quality=95, **fields)


def test_a_view_from_a_rig_camera_shows_what_that_camera_saw(session, take):
    header, data = session.view("v", at_camera(take, 2, id=11, frame=1))
    image = decode(data)
    sil = take.silhouettes[1][2]
    inside = cv2.erode(sil.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)  # away from JPEG edge blocks
    assert image.shape == (72, 96, 3)
    truth = decode(jpeg(take.frames[1][2], 95))  # the same picture through the same JPEG encoder
    assert np.abs(image[inside].astype(int) - truth[inside]).mean() < 3
    assert header["id"] == 11 and header["frame"] == 1 and header["seq"] is None
    assert 0.6 * sil.mean() < header["coverage"] < 1.6 * sil.mean()
    near, far = header["depth_range"]
    assert near < header["depth_found"][0] <= header["depth_found"][1] <= far * (1 + 1e-6)  # depth is float32
    assert header["render_ms"] > 0 and header["reshaded"] is False


def test_changing_only_the_weighting_reshades_the_same_depth(session, take):
    first, _ = session.view("v", at_camera(take, 1, method="kojima"))
    second, _ = session.view("v", at_camera(take, 1, method="nearest"))
    other, _ = session.view("w", at_camera(take, 1, method="nearest"))
    assert second["reshaded"] is True and other["reshaded"] is False  # per viewer
    assert second["depth_found"] == first["depth_found"]
    moved, _ = session.view("v", Viewpoint(orbit=Orbit(azimuth=3.0), width=96, height=72, planes=PLANES))
    assert moved["reshaded"] is False


def test_d_bnd_is_derived_from_the_rig_unless_the_viewer_sets_it(session, take):
    derived, _ = session.view("v", at_camera(take, 1, method="kojima"))
    chosen, _ = session.view("v", at_camera(take, 1, method="kojima", d_bnd=0.02))
    assert derived["d_bnd"] is not None and 0 < derived["d_bnd"] <= 2 and derived["d_bnd"] != 0.02
    assert chosen["d_bnd"] == 0.02 and chosen["reshaded"] is True


def test_k_camera_blending_is_a_viewer_method(session, take):
    """method "kojima_k" (every camera within D_bnd of the nearest one blended) reshades the same depth, with its
    D_bnd derived from the rig like kojima's or set by the viewer."""
    first, _ = session.view("v", at_camera(take, 1, method="kojima"))
    kk, data = session.view("v", at_camera(take, 1, method="kojima_k"))
    assert kk["reshaded"] is True and kk["method"] == "kojima_k" and kk["d_bnd"] == first["d_bnd"]
    chosen, _ = session.view("v", at_camera(take, 1, method="kojima_k", d_bnd=0.3, overlay="regions"))
    assert chosen["d_bnd"] == 0.3 and decode(data).shape == (72, 96, 3)


def test_overlays_change_the_picture(session, take):
    _, plain = session.view("v", at_camera(take, 0))
    _, regions = session.view("v", at_camera(take, 0, overlay="regions"))
    _, depth = session.view("v", at_camera(take, 0, overlay="depth"))
    a, b, c = decode(plain).astype(int), decode(regions).astype(int), decode(depth).astype(int)
    surface = cv2.erode((a.max(axis=2) > 0).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert np.abs(b - a)[surface].mean() > 10  # tinted where there is a surface
    assert np.abs(b - a)[~surface].mean() < 3  # and left alone elsewhere (up to JPEG)
    assert np.abs(c - a).mean() > 10


def test_requests_over_the_limits_or_out_of_range_are_view_errors(session, take):
    with pytest.raises(ViewError, match="over the limit of 40,000 pixels") as e:
        session.view("v", Viewpoint(width=320, height=240))
    assert e.value.code == "too_large"
    with pytest.raises(ViewError, match="64"):
        session.view("v", Viewpoint(width=96, height=72, planes=128))
    with pytest.raises(ViewError, match="frame 3 is out of range"):
        session.view("v", Viewpoint(width=96, height=72, frame=3))
    with pytest.raises(ViewError, match="must be a frame index"):
        session.view("v", Viewpoint(width=96, height=72, frame="live"))
    with pytest.raises(ViewError, match="behind"):
        session.view("v", Viewpoint(width=96, height=72, look_at={"eye": [0, 3, 0.5], "target": [0, 6, 0.5]}))


def test_live_session_shows_the_latest_set_and_keeps_it_on_bad_input(take):
    live = LiveSession(take.rig, SessionLimits())
    with pytest.raises(ViewError, match="no live frame set"):
        live.view("v", Viewpoint(frame="live", width=96, height=72))
    ack = live.push([jpeg(b) for b in take.backgrounds], is_background=True)
    assert ack["seq"] == 1 and ack["background_model"] is True
    empty, _ = live.view("v", Viewpoint(frame="live", width=96, height=72, planes=PLANES))
    assert empty["coverage"] == 0  # the empty studio has no silhouette
    live.push([jpeg(i) for i in take.frames[0]])
    header, _ = live.view("v", Viewpoint(frame="live", width=96, height=72, planes=PLANES))
    assert header["seq"] == 2 and header["frame"] == "live" and header["coverage"] > 0.05
    broken = [jpeg(i) for i in take.frames[1]]
    broken[2] = broken[2][: len(broken[2]) // 3]
    with pytest.raises(ViewError, match="camera cam02: the image does not decode") as e:
        live.push(broken)
    assert e.value.code == "bad_image" and live.seq == 2
    with pytest.raises(ViewError, match="is 48x36, the calibration says 96x72"):
        live.push([jpeg(cv2.resize(i, (48, 36))) for i in take.frames[1]])
    with pytest.raises(ViewError, match="3 images for 4 cameras"):
        live.push([jpeg(i) for i in take.frames[1][:3]])
    with pytest.raises(ViewError, match="must be \"live\""):
        live.view("v", Viewpoint(frame=0, width=96, height=72))


def test_background_model_follows_light_but_not_the_subject():
    model = BackgroundModel(1, rate=0.5, threshold=20)
    studio = np.full((20, 20, 3), 100, np.uint8)
    assert model.observe([studio], False) is None
    model.observe([studio], True)
    frame = np.full((20, 20, 3), 110, np.uint8)  # lights up a little
    frame[5:15, 5:15] = 250  # the subject
    for _ in range(10):
        sil = model.observe([frame], False)[0]
    assert sil[7:13, 7:13].all() and not sil[:3].any()
    bg = model.images()[0]
    assert abs(int(bg[0, 0, 0]) - 110) <= 1 and abs(int(bg[10, 10, 0]) - 100) <= 1


def test_session_limits_check_is_the_one_view_rule():
    limits = SessionLimits(max_pixels=100 * 100, max_planes=64)
    limits.check(100, 100, 64)  # at the limits: allowed
    with pytest.raises(ViewError, match="output 101x100 is over the limit of 10,000 pixels") as e:
        limits.check(101, 100, 8)
    assert e.value.code == "too_large"
    with pytest.raises(ViewError, match="65 planes is over the limit of 64") as e:
        limits.check(10, 10, 65)
    assert e.value.code == "too_many_planes"


def test_reduced_decoding_matches_area_averaging_and_checks_the_size(take):
    image = take.frames[0][1]  # 96x72
    data = jpeg(image, 95)
    full = decode_image(data, (96, 72))
    for factor in (1, 2, 3, 4, 8):
        small = decode_reduced(data, (96, 72), factor)
        w, h = reduced_size((96, 72), factor)
        assert small.shape == (h, w, 3) and small.dtype == np.uint8
        # DCT scaling (2, 4, 8) and area averaging (3) give the same picture, pixel centres aligned
        area = cv2.resize(full, (w, h), interpolation=cv2.INTER_AREA).astype(int)
        assert np.abs(small.astype(int) - area).mean() < 2.0
    with pytest.raises(ImageError, match="is 96x72, the calibration says 48x36"):
        decode_reduced(data, (48, 36), 2)
    with pytest.raises(ImageError, match="does not decode"):
        decode_reduced(data[: len(data) // 3], (96, 72), 2)


def test_live_frames_are_decoded_at_the_size_the_viewers_need(take):
    live = LiveSession(take.rig, SessionLimits())
    live.push([jpeg(b) for b in take.backgrounds], is_background=True)
    live.push([jpeg(i) for i in take.frames[0]])
    assert live.source_factor == 1  # no viewer yet: the protocol's default size (320x240) needs every pixel
    small = Viewpoint(frame="live", width=48, height=36, planes=PLANES)
    header, _ = live.view("small", small)
    assert header["source_factor"] == 1  # the set on show was decoded before this viewer came
    ack = live.push([jpeg(i) for i in take.frames[1]])
    assert ack["source_factor"] == 2 and live.renderer.cameras[0].width == 48  # the next set: half size
    assert live.background.images()[0].shape == (36, 48, 3)  # the model follows
    header, _ = live.view("small", small)
    assert header["source_factor"] == 2 and header["seq"] == 3 and header["coverage"] > 0.02
    header, _ = live.view("big", Viewpoint(frame="live", width=96, height=72, planes=PLANES))
    assert header["source_factor"] == 1 and header["seq"] == 3  # the same set, decoded again at full size at once
    assert header["coverage"] > 0.05
    live.forget("big")
    assert live.push([jpeg(i) for i in take.frames[0]])["source_factor"] == 2


def test_a_live_set_decoded_for_another_factor_is_decoded_again(take):
    live = LiveSession(take.rig, SessionLimits())
    jpegs = [jpeg(i) for i in take.frames[0]]
    images = live.decode(jpegs, factor=2)
    live.apply(images, jpegs)  # the session wants factor 1 (no viewer): the set is decoded again
    assert live.source_factor == 1 and live.seq == 1
    assert live.renderer.cameras[0].width == 96
