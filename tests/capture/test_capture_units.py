"""The capture side's parts without any network: sources, clocks, the newest-frames mailbox, set assembly."""
from __future__ import annotations

import random
import struct

import numpy as np
import pytest

from app.capture.assembly import SetAssembler
from app.capture.clocks import ArrivalAnchor, CaptureClock, prft_seconds
from app.capture.mailbox import Frame, FrameMailbox
from app.capture.sources import SourceError, parse_offsets, parse_sources

CAMS = ["left", "mid", "right"]


def test_sources_in_rig_order_or_by_name(tmp_path):
    clip = tmp_path / "clip.mp4"
    clip.write_bytes(b"x")
    plain = parse_sources(["rtsp://a/1", "/dev/video0", str(clip)], CAMS)
    assert [(s.camera, s.name, s.kind) for s in plain] == [(0, "left", "network"), (1, "mid", "v4l2"), (2, "right", "file")]
    named = parse_sources(["right=rtsp://u:secret@c/x?a=b", "left=v4l2:2", "mid=udp://0.0.0.0:5000"], CAMS)
    assert [s.target for s in named] == ["v4l2:2", "udp://0.0.0.0:5000", "rtsp://u:secret@c/x?a=b"]
    assert named[2].shown == "rtsp://u:***@c/x?a=b"  # messages never show a camera's password
    for args, says in [(["rtsp://a"], "the rig has 3 cameras"), (["left=rtsp://a", "rtsp://b", "rtsp://c"], "mixing"),
                       (["left=rtsp://a", "left=rtsp://b", "mid=rtsp://c"], "given twice"),
                       (["left=rtsp://a", "mid=rtsp://b"], "no source for camera"),
                       (["rtsp://a", "rtsp://b", "nowhere.mp4"], "camera right: nowhere.mp4 is neither")]:
        with pytest.raises(SourceError, match=says):
            parse_sources(args, CAMS if len(args) == 3 or "=" in args[0] else CAMS)
    assert parse_offsets(["mid=-40", "right=12.5"], CAMS) == [0.0, -0.04, 0.0125]
    with pytest.raises(SourceError, match="expected NAME=MILLISECONDS"):
        parse_offsets(["nobody=3"], CAMS)


def test_the_producer_reference_time_is_read_as_ffmpeg_writes_it():
    wallclock_us = 1_796_509_665_575_517
    assert prft_seconds(struct.pack("<qi", wallclock_us, 24) + b"\0" * 4) == pytest.approx(wallclock_us / 1e6, abs=1e-6)


def test_arrival_anchoring_ignores_jitter_and_follows_drift():
    """A camera clock 200 ppm fast, frames at 25 fps, 5-60 ms of random delay: capture times stay within a few ms
    of the truth (the least-delayed frames anchor them) for ten minutes, where the drift alone adds 120 ms."""
    rng = random.Random(1)
    anchor = ArrivalAnchor(window_s=10.0)
    errors = []
    for k in range(25 * 600):
        true = 1_000.0 + k / 25
        stream_time = 50.0 + (true - 1_000.0) * (1 + 200e-6)  # the camera's own timestamps, another origin
        arrival = true + 0.005 + rng.expovariate(1 / 0.02)
        errors.append(anchor.stamp(stream_time, arrival) - true)
    late = np.array(errors[25 * 20:])  # after the first window
    assert 0.004 < np.median(late) < 0.010 and late.max() < 0.015 and late.min() > 0.0  # the floor: the least delay
    # a restarted stream (its timestamps start over) is anchored anew at once
    assert anchor.stamp(0.0, 2_000.0) == pytest.approx(2_000.0)


def test_the_clock_prefers_the_camera_then_a_file_then_arrival_and_applies_the_offset():
    clock = CaptureClock(offset_s=-0.25)
    assert clock.stamp(100.0, camera_time=99.0) == pytest.approx(98.75) and clock.kind == "camera"
    assert clock.stamp(100.0, file_time=99.5, stream_time=3.0) == pytest.approx(99.25) and clock.kind == "file"
    assert clock.stamp(100.04, stream_time=3.04) == pytest.approx(99.79) and clock.kind == "arrival"
    assert clock.stamp(101.0) == pytest.approx(100.75)
    assert clock.delay_ms == pytest.approx(500.0)  # the median of 1250, 750, 250 and 250 ms behind arrival


def test_the_mailbox_keeps_only_the_newest_frames():
    box = FrameMailbox(keep=3)
    for k in range(10):
        box.put(Frame(0, np.zeros((2, 2, 3), np.uint8), float(k), float(k), k))
    assert [f.number for f in box.recent()] == [7, 8, 9] and box.received == 10 and box.newest().number == 9


class Rig:
    """Mailboxes of simulated cameras on a shared arrival clock."""

    def __init__(self, n: int, keep: int = 8) -> None:
        self.now = 0.0
        self.boxes = [FrameMailbox(keep) for _ in range(n)]
        self.numbers = [0] * n

    def frame(self, camera: int, capture: float, arrival: float | None = None) -> None:
        self.numbers[camera] += 1
        self.boxes[camera].put(Frame(camera, np.zeros((2, 2, 3), np.uint8), capture,
                                     self.now if arrival is None else arrival, self.numbers[camera]))


def test_sets_are_the_newest_instant_within_the_tolerance_and_never_sent_twice():
    rig = Rig(3)
    sets = SetAssembler(rig.boxes, tolerance=0.02, missing_seconds=1.0, clock=lambda: rig.now)
    for k in range(3):  # three instants; camera 2's frames run 3 ms late on its clock
        for c in range(3):
            rig.frame(c, k * 0.04 + (0.003 if c == 2 else 0.0))
    rig.frame(0, 0.12)  # camera 0 already has the next instant, the others not yet
    rig.frame(1, 0.12)
    first = sets.next_set()
    assert [f.capture for f in first.frames] == pytest.approx([0.08, 0.08, 0.083])  # the newest complete instant
    assert first.spread == pytest.approx(0.003) and first.stale == [False] * 3
    assert sets.next_set() is None  # 0.12 is not complete: camera 2's nearest frame is 37 ms away
    rig.frame(2, 0.121)
    second = sets.next_set()
    assert [f.capture for f in second.frames] == pytest.approx([0.12, 0.12, 0.121])
    assert sets.next_set() is None  # nothing newer: the same instant is never sent again


def test_no_set_when_no_instant_is_within_the_tolerance_and_the_status_knows_the_best_spread():
    rig = Rig(2)
    sets = SetAssembler(rig.boxes, tolerance=0.005, missing_seconds=1.0, clock=lambda: rig.now)
    for k in range(4):  # free-running cameras 20 ms out of phase
        rig.frame(0, k * 0.04)
        rig.frame(1, k * 0.04 + 0.02)
    assert sets.next_set() is None and sets.best_failed_spread == pytest.approx(0.02)


def test_a_silent_camera_is_waited_for_then_sent_stale():
    rig = Rig(3)
    sets = SetAssembler(rig.boxes, tolerance=0.02, missing_seconds=0.5, clock=lambda: rig.now)
    for c in range(3):
        rig.frame(c, 0.0)
    assert sets.next_set().stale == [False] * 3
    for k in range(1, 6):  # camera 1 falls silent
        rig.now = k * 0.04
        rig.frame(0, rig.now)
        rig.frame(2, rig.now)
    assert sets.next_set() is None and sets.missing() == [False, False, False]  # a late frame is not a lost camera
    rig.now = 0.6
    rig.frame(0, 0.6)
    rig.frame(2, 0.6)
    made = sets.next_set()
    assert made.stale == [False, True, False] and made.frames[1].capture == 0.0  # its last frame, marked stale
    assert made.spread == 0.0 and made.instant == pytest.approx(0.6)


def test_a_camera_that_never_sent_a_frame_goes_stale_without_one():
    rig = Rig(3)
    sets = SetAssembler(rig.boxes, tolerance=0.02, missing_seconds=0.5, clock=lambda: rig.now)
    rig.frame(0, 0.0)
    rig.frame(1, 0.0)
    assert sets.next_set() is None
    rig.now = 0.6
    rig.frame(0, 0.6)
    rig.frame(1, 0.6)
    made = sets.next_set()
    assert made.stale == [False, False, True] and made.frames[2] is None


def test_sweepcast_live_says_why_it_cannot_start(capsys):
    from app.cli import main
    from harness.servers import free_port

    assert main(["live", "rig1", "rtsp://a/1", "rtsp://b/2", "--server", f"http://127.0.0.1:{free_port()}"]) == 2
    said = capsys.readouterr().err
    assert said.startswith("sweepcast live: ws://127.0.0.1:") and "/v1/rigs/rig1/live: cannot reach the service" in said


def test_the_settings_page_lists_every_setting_of_sweepcast_live():
    from pathlib import Path

    from app.capture.settings import CaptureSettings

    page = (Path(__file__).resolve().parents[2] / "docs" / "settings.md").read_text()
    missing = [f"SWEEPCAST_LIVE_{name.upper()}" for name in CaptureSettings.model_fields
               if f"SWEEPCAST_LIVE_{name.upper()}" not in page]
    assert missing == []
