"""Frames (selection, blur, undistortion) and calibration parsing."""
import cv2
import numpy as np
import pytest

from workers.common.jobctx import JobInputError
from workers.drone.calibration import from_values, parse_calibration
from workers.drone.frames import SelectionStats, open_media, select_frames
from workers.synth.flight import encode_video


def _frames(n=24, blur_every=None):
    rng = np.random.default_rng(0)
    base = cv2.resize(rng.integers(0, 256, (60, 80, 3), dtype=np.uint8), (640, 480), interpolation=cv2.INTER_CUBIC)
    out = []
    for i in range(n):
        img = np.roll(base, 4 * i, axis=1)[:, :320][:240].copy()  # 4 px per frame to the right
        if blur_every and i % blur_every == blur_every - 1:
            img = cv2.GaussianBlur(img, (0, 0), 4)
        out.append(img)
    return out


INTR = from_values(300, 300, 159.5, 119.5)


def test_every_kth_frame_and_blur_skipping(tmp_path):
    path = encode_video(_frames(24, blur_every=4), tmp_path / "v.mp4")
    stats = SelectionStats()
    frames = list(select_frames(open_media(path), INTR, frame_step=1, blur_ratio=0.5, stats=stats))
    idx = [f.index for f in frames]
    # The blur test needs five frames of history: frames 7, 11, ... 23 are caught.
    assert stats.decoded == 24 and stats.skipped_blurred == 5
    assert not any(i % 4 == 3 for i in idx if i > 5)
    frames = list(select_frames(open_media(path), INTR, frame_step=3, blur_ratio=0.0))
    assert [f.index for f in frames] == list(range(0, 24, 3))
    capped = SelectionStats()
    frames = list(select_frames(open_media(path), INTR, frame_step=1, blur_ratio=0.0, max_frames=5, stats=capped))
    assert len(frames) <= 5 and capped.stride == 5


def test_adaptive_selection_follows_motion_and_resizes(tmp_path):
    path = encode_video(_frames(24), tmp_path / "v.mp4")
    stats = SelectionStats()
    frames = list(select_frames(open_media(path), INTR, None, min_motion=15 / 320, blur_ratio=0.0,
                                max_width=160, stats=stats))
    # 4 px per frame: a frame once the image moved 15 px, i.e. every 4th.
    assert [f.index for f in frames] == list(range(0, 24, 4))
    assert frames[0].image.shape == (120, 160, 3) and stats.scale == 0.5


def test_undistortion_straightens_lines(tmp_path):
    img = np.full((240, 320, 3), 255, np.uint8)
    K = INTR.K
    dist = np.array([-0.3, 0.08, 0.0, 0.0])
    # Draw a straight line as the distorted camera would see it.
    x = np.linspace(-0.5, 0.5, 400)
    pts = np.column_stack([x, np.full_like(x, 0.3), np.ones_like(x)])
    uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, dist)
    cv2.polylines(img, [np.rint(uv).astype(np.int32)], False, (0, 0, 0), 2)
    path = encode_video([img] * 2, tmp_path / "d.mp4")
    frame = next(select_frames(open_media(path), from_values(300, 300, 159.5, 119.5, list(dist))))
    ys, xs = np.nonzero(frame.gray[:, 40:280] < 128)
    assert np.ptp(np.polyfit(xs, ys, 2)[0] * 1000) < 0.5  # no curvature left
    assert abs(np.median(ys) - (119.5 + 0.3 * 300)) < 2.0


def test_calibration_formats():
    fs = cv2.FileStorage("out.yml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    fs.write("camera_matrix", np.array([[700.0, 0, 600], [0, 710.0, 450], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.array([[0.1, -0.05, 0.0, 0.0, 0.0]]))
    intr = parse_calibration(fs.releaseAndGetString())
    assert (intr.fx, intr.fy, intr.cx, intr.cy) == (700, 710, 600, 450)
    np.testing.assert_allclose(intr.dist, [0.1, -0.05, 0, 0, 0])
    intr = parse_calibration(b"# cameras\n1 SIMPLE_RADIAL 1200 900 702 600 450 -0.02\n")
    assert (intr.fx, intr.fy, intr.cx, intr.cy) == (702, 702, 599.5, 449.5)
    np.testing.assert_allclose(intr.dist, [-0.02, 0, 0, 0])
    assert parse_calibration("500, 501, 320, 240").fy == 501
    assert parse_calibration('{"K": [[500, 0, 320], [0, 500, 240], [0, 0, 1]]}').cx == 320
    assert parse_calibration("500 0 320 0 500 240 0 0 1").cy == 240
    for bad in ("", "hello world", '{"fx": "a", "fy": 1, "cx": 1, "cy": 1}', b"\xff\xfe\x00"):
        with pytest.raises(JobInputError):
            parse_calibration(bad)


def test_intrinsics_checks_and_scaling():
    INTR.check(320, 240)
    with pytest.raises(JobInputError, match="differ too much"):
        from_values(300, 3000, 160, 120).check(320, 240)
    with pytest.raises(JobInputError, match="implausible"):
        from_values(2, 2, 160, 120).check(320, 240)
    half = INTR.scaled(0.5)
    assert (half.fx, half.cx) == (150, 79.5)
