"""The reader-process design the live_ingest benchmark measures against reader threads (benchmarks/_reader_process.py):
its frames reach the parent whole, with their capture times, and a frame overwritten before it was copied is never
delivered."""
import threading
import time

import numpy as np

from app.capture.mailbox import FrameMailbox
from benchmarks._reader_process import RING_SLOTS, FrameRing, ProcessReader
from harness.rtsp_camera import Camera, RtspServer, read_instant


def test_a_slot_gives_back_its_frame_until_the_child_writes_over_it():
    ring = FrameRing(None, 16, 8, create=True)
    try:
        first = np.random.default_rng(0).integers(0, 256, (8, 16, 3), np.uint8)
        slot = ring.write(first, 5)
        copy = ring.read(slot, 5)
        assert np.array_equal(copy, first)
        ring.write(np.zeros_like(first), 5 + RING_SLOTS)  # the same slot, a later frame
        assert ring.read(slot, 5) is None
        assert np.array_equal(copy, first)  # what was copied out stays the parent's
    finally:
        ring.close(unlink=True)


class _Waking(FrameMailbox):
    def __init__(self) -> None:
        super().__init__(keep=8)
        self.arrived = threading.Event()

    def put(self, frame) -> None:
        super().put(frame)
        self.arrived.set()


def test_a_reader_process_hands_over_whole_frames_with_the_cameras_capture_times():
    camera = Camera("cam", 160, 120, fps=25.0, clock_offset=0.5)  # its clock half a second ahead of ours
    mailbox = _Waking()
    with RtspServer([camera]) as server:
        reader = ProcessReader(0, server.url("cam"), (160, 120), mailbox)
        try:
            deadline = time.monotonic() + 30
            while mailbox.received < 10 and time.monotonic() < deadline:
                mailbox.arrived.wait(0.5)
        finally:
            reader.stop()
    frames = mailbox.recent()
    assert mailbox.received >= 10, "the reader process handed over fewer than 10 frames in 30 s"
    for frame in frames:
        image = frame.bgr()
        assert image.shape == (120, 160, 3) and image.dtype == np.uint8
        k = read_instant(image)  # the trigger index the camera drew into this frame
        assert abs(frame.capture - camera.clock(camera.sent[k])) < 0.002  # stamped with the camera's own clock
    assert [f.number for f in frames] == sorted(f.number for f in frames)
