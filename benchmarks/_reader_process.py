"""One reader *process* per camera: the alternative to ``sweepcast live``'s reader threads, built to be measured
against them (``benchmarks/live_ingest.py``, section ``readers``), not used by the service.

A real process design has to move every decoded frame to the process that assembles the sets. Here, as such a
design would: the child (``python -m benchmarks._reader_process CAMERA URL WIDTH HEIGHT RING``) runs the capture
side's own :class:`app.capture.readers.CameraReader` (the same demuxing, decoding, clock and reconnects as a reader
thread), converts each frame to BGR and writes it into a ring of frame slots in shared memory (:class:`FrameRing`),
then tells the parent which slot holds which frame in a fixed-size record on its standard output (a pipe). The
parent (:class:`ProcessReader`) has one thread per child that reads those records, copies the frame out of its slot
(the child writes the slot again ``RING_SLOTS`` frames later) and puts it in the camera's mailbox, where the set
assembler finds it as it finds a reader thread's frames. The child stops when its standard input closes.
"""
from __future__ import annotations

import os
import struct
import subprocess
import sys
import threading
from multiprocessing import resource_tracker, shared_memory
from pathlib import Path
from typing import Any

import numpy as np

from app.capture.mailbox import Frame, FrameMailbox

RING_SLOTS = 8
"""Frame slots per camera, as many as a mailbox keeps frames (``CaptureSettings.keep_frames``' default): the parent
copies a frame out within milliseconds of its record, but a reader that has just connected decodes the frames FFmpeg
buffered while probing the stream (0.2 s: five frames) in one burst. A frame overwritten before it was copied is
counted (``torn``), never delivered: an old frame dropped, as a mailbox drops its oldest."""
REPOSITORY = Path(__file__).resolve().parents[1]
"""Where ``python -m benchmarks._reader_process`` finds its modules, whatever the caller's working directory."""
RECORD = struct.Struct("<qqdd")
"""One frame handed over: slot, frame number, capture time, arrival time (s since the epoch)."""
WRITING = -1


class FrameRing:
    """``slots`` frames of (height, width, 3) uint8 BGR in one shared-memory block, each behind an int64 header that
    holds the number of the frame in it (``WRITING`` while the child writes it): a sequence lock, so that the parent
    can tell a frame overwritten while it copied. ``create=True``: the parent makes it (and unlinks it)."""

    def __init__(self, name: str | None, width: int, height: int, slots: int = RING_SLOTS, create: bool = False):
        self.shape = (height, width, 3)
        self.slots = slots
        frame_bytes = height * width * 3
        self._shm = shared_memory.SharedMemory(name=name, create=create, size=8 * slots + frame_bytes * slots)
        self.name = self._shm.name
        self.headers = np.ndarray((slots,), np.int64, self._shm.buf)
        self.frames = np.ndarray((slots, *self.shape), np.uint8, self._shm.buf, offset=8 * slots)
        if create:
            self.headers[:] = WRITING
        else:  # only its maker unlinks it: Python < 3.13 would make this process's resource tracker unlink it too
            resource_tracker.unregister(self._shm._name, "shared_memory")  # noqa: SLF001 - the name it registered

    def write(self, image: np.ndarray, number: int) -> int:
        """Put ``image`` ((height, width, 3) uint8) as frame ``number`` in the next slot; returns the slot."""
        slot = number % self.slots
        self.headers[slot] = WRITING
        self.frames[slot] = image
        self.headers[slot] = number
        return slot

    def read(self, slot: int, number: int) -> np.ndarray | None:
        """A copy of frame ``number`` from ``slot``, or None when the child has written over it."""
        if self.headers[slot] != number:
            return None
        image = self.frames[slot].copy()
        return image if self.headers[slot] == number else None

    def close(self, unlink: bool = False) -> None:
        del self.headers, self.frames  # the block cannot close while arrays still point into it
        self._shm.close()
        if unlink:
            self._shm.unlink()


class ProcessReader:
    """The parent's side of one reader process: starts the child for camera ``camera`` (rig index) at ``url`` and
    puts the frames it hands over into ``mailbox``. ``torn``: frames overwritten before they were copied; ``pid``: the
    child's."""

    def __init__(self, camera: int, url: str, size: tuple[int, int], mailbox: FrameMailbox) -> None:
        self.camera = camera
        self.mailbox = mailbox
        self.ring = FrameRing(None, *size, create=True)
        self.torn = 0
        self._child = subprocess.Popen([sys.executable, "-m", "benchmarks._reader_process", str(camera), url,
                                        str(size[0]), str(size[1]), self.ring.name],
                                       stdin=subprocess.PIPE, stdout=subprocess.PIPE, cwd=REPOSITORY)
        self.pid = self._child.pid
        self._thread = threading.Thread(target=self._receive, name=f"receiver-{camera}", daemon=True)
        self._thread.start()

    def _receive(self) -> None:
        while record := self._child.stdout.read(RECORD.size):
            if len(record) < RECORD.size:
                break
            slot, number, capture, arrival = RECORD.unpack(record)
            image = self.ring.read(slot, number)
            if image is None:
                self.torn += 1
                continue
            self.mailbox.put(Frame(self.camera, image, capture, arrival, number))

    def stop(self, timeout: float = 10.0) -> None:
        """Close the child's input (it stops its reader and exits), wait for it, free the ring."""
        self._child.stdin.close()
        try:
            self._child.wait(timeout)
        except subprocess.TimeoutExpired:
            self._child.kill()
            self._child.wait()
        self._thread.join(timeout)
        self.ring.close(unlink=True)


class _RingMailbox(FrameMailbox):
    """The child's mailbox: every frame the reader decodes goes to the ring and its record to the parent."""

    def __init__(self, ring: FrameRing, out_fd: int) -> None:
        super().__init__(keep=1)
        self.ring = ring
        self.out_fd = out_fd

    def put(self, frame: Frame) -> None:
        slot = self.ring.write(frame.bgr(), frame.number)
        os.write(self.out_fd, RECORD.pack(slot, frame.number, frame.capture, frame.arrival))


def child(camera: int, url: str, width: int, height: int, ring_name: str) -> None:
    """The reader process (module docstring): records on the standard output, messages on the standard error."""
    from app.capture.clocks import CaptureClock
    from app.capture.readers import CameraReader
    from app.capture.settings import CaptureSettings
    from app.capture.sources import Source

    out_fd = os.dup(1)
    os.dup2(2, 1)  # nothing printed by accident can corrupt the records
    ring = FrameRing(ring_name, width, height)
    settings = CaptureSettings()
    reader = CameraReader(Source(camera, f"camera{camera}", "rtsp", url), (width, height), CaptureClock(),
                          _RingMailbox(ring, out_fd), settings,
                          report=lambda message: print(message, file=sys.stderr, flush=True))
    reader.start()
    sys.stdin.read()
    reader.stop()
    ring.close()


def main(argv: list[str]) -> Any:
    camera, url, width, height, ring_name = argv
    child(int(camera), url, int(width), int(height), ring_name)


if __name__ == "__main__":
    main(sys.argv[1:])
