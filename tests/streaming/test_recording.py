"""Recordings: checks against the rig, archives, imports from videos and image folders."""
import io
import zipfile

import numpy as np
import pytest

from harness.takes import write_videos, zip_bytes
from workers.streaming.recording import (ArchiveWriter, RecordingArchive, RecordingError, check_image_sizes,
                                         check_videos, import_image_zip, import_videos, match_cameras,
                                         scan_image_zip, temporal_median)
from workers.streaming.video import VideoInfo, decode_frames, probe_video


def info(frames=10, w=96, h=72, fps=10.0):
    return VideoInfo(frames, w, h, fps, "h264")


def test_archive_round_trip_is_lossless(take, tmp_path):
    writer = ArchiveWriter(tmp_path / "a.zip", take.rig, 12.5)
    for frame in take.frames:
        for c, image in enumerate(frame):
            writer.add(c, image)
    for c, bg in enumerate(take.backgrounds):
        writer.set_background(c, bg)
    written = writer.finish("given")
    archive = RecordingArchive(tmp_path / "a.zip")
    assert archive.info == written
    assert (archive.info.frames, archive.info.fps, archive.info.cameras) == (3, 12.5, tuple(take.rig.names))
    for f in range(3):
        for got, want in zip(archive.frame_set(f), take.frames[f]):
            np.testing.assert_array_equal(got, want)
    for got, want in zip(archive.backgrounds(), take.backgrounds):
        np.testing.assert_array_equal(got, want)
    with pytest.raises(IndexError, match="out of range"):
        archive.frame_set(3)


def test_archive_refuses_unequal_cameras(take, tmp_path):
    writer = ArchiveWriter(tmp_path / "a.zip", take.rig, 10)
    for c, image in enumerate(take.frames[0]):
        writer.add(c, image)
    writer.add(0, take.frames[1][0])
    with pytest.raises(RecordingError, match="differ in length"):
        writer.finish("median")
    with pytest.raises(RecordingError, match=r"\(72, 96, 3\) uint8"):
        writer.add(1, np.zeros((10, 10, 3), np.uint8))


def test_uploads_match_cameras_by_name_then_by_order(take):
    rig = take.rig
    assert match_cameras(["cam02.mp4", "cam00.mp4", "cam03.avi", "cam01.mkv"], rig) == [2, 0, 3, 1]
    assert match_cameras(["a.mp4", "b.mp4", "c.mp4", "d.mp4"], rig) == [0, 1, 2, 3]
    with pytest.raises(RecordingError, match="got 2 videos for 4 cameras"):
        match_cameras(["a.mp4", "b.mp4"], rig)


def test_video_checks(take):
    rig = take.rig
    labels = [f"{n}.mp4" for n in rig.names]
    assert check_videos([(lb, info()) for lb in labels], [0, 1, 2, 3], rig, 100) == (10, 10.0)
    with pytest.raises(RecordingError, match=r"differ in length \(cam00.mp4: 10, cam01.mp4: 9"):
        check_videos([(lb, info(frames=9 if i == 1 else 10)) for i, lb in enumerate(labels)], [0, 1, 2, 3], rig, 100)
    with pytest.raises(RecordingError, match="cam02.mp4 \\(camera cam02\\) is 640x480; the calibration says 96x72"):
        check_videos([(lb, info(w=640, h=480) if i == 2 else info()) for i, lb in enumerate(labels)],
                     [0, 1, 2, 3], rig, 100)
    with pytest.raises(RecordingError, match="frame rates differ"):
        check_videos([(lb, info(fps=25.0 if i == 3 else 10.0)) for i, lb in enumerate(labels)], [0, 1, 2, 3], rig, 100)
    with pytest.raises(RecordingError, match="limit is 5"):
        check_videos([(lb, info()) for lb in labels], [0, 1, 2, 3], rig, 5)
    with pytest.raises(RecordingError, match="missing: cam03"):
        check_videos([(lb, info()) for lb in labels[:3]], [0, 1, 2], rig, 100)


def test_image_zip_layout(take):
    rig = take.rig
    with zipfile.ZipFile(io.BytesIO(zip_bytes(take))) as zf:
        folders = scan_image_zip(zf, rig, 100)
        check_image_sizes(zf, folders, rig)
    assert folders.frames[1] == ["take/cam01/frame1.png", "take/cam01/frame2.png", "take/cam01/frame3.png"]
    assert folders.backgrounds[3] == "take/backgrounds/cam03.png"
    with zipfile.ZipFile(io.BytesIO(zip_bytes(take, frames=[3, 3, 2, 3]))) as zf:
        with pytest.raises(RecordingError, match="differ in length.*cam02: 2"):
            scan_image_zip(zf, rig, 100)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("cam00/1.png", b"x")
        zf.writestr("elsewhere/1.png", b"x")
    with zipfile.ZipFile(buf) as zf, pytest.raises(RecordingError, match="'elsewhere' is not a rig camera"):
        scan_image_zip(zf, rig, 100)


def test_import_from_h264_videos(take, tmp_path):
    paths = write_videos(take, tmp_path)
    labels = [p.name for p in paths]
    infos = [(p.name, probe_video(p)) for p in paths]
    frames, fps = check_videos(infos, match_cameras(labels, take.rig), take.rig, 100)
    assert (frames, fps) == (3, 10.0)
    progress = []
    result = import_videos(list(zip(labels, paths)), [0, 1, 2, 3], take.rig, tmp_path / "rec.zip", frames, fps,
                           progress=lambda f, s: progress.append(f))
    assert result.background == "median" and result.frames == 3
    assert progress and progress[-1] <= 1.0
    archive = RecordingArchive(tmp_path / "rec.zip")
    decoded = [list(decode_frames(p)) for p in paths]
    for f in range(3):
        for c, got in enumerate(archive.frame_set(f)):
            np.testing.assert_array_equal(got, decoded[c][f])  # stored losslessly as decoded
            assert np.abs(got.astype(int) - take.frames[f][c]).mean() < 20  # and it is the take
    np.testing.assert_array_equal(archive.backgrounds()[0], temporal_median(decoded[0]))


def test_import_refuses_a_video_shorter_than_probed(take, tmp_path):
    paths = write_videos(take, tmp_path, frames=[3, 3, 2, 3])
    with pytest.raises(RecordingError, match="cam02.mp4 decodes to 2 frames, not 3"):
        import_videos([(p.name, p) for p in paths], [0, 1, 2, 3], take.rig, tmp_path / "rec.zip", 3, 10.0)


def test_import_from_image_folders_keeps_the_given_backgrounds(take, tmp_path):
    (tmp_path / "in.zip").write_bytes(zip_bytes(take))
    result = import_image_zip(tmp_path / "in.zip", take.rig, tmp_path / "rec.zip", 5.0, 100)
    assert (result.frames, result.fps, result.background) == (3, 5.0, "given")
    archive = RecordingArchive(tmp_path / "rec.zip")
    np.testing.assert_array_equal(archive.frame_set(2)[1], take.frames[2][1])
    np.testing.assert_array_equal(archive.backgrounds()[3], take.backgrounds[3])
