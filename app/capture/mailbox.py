"""A camera's newest frames: what its reader decoded, for the set assembler to choose from.

The reader puts every frame it decodes (an H.264 stream must be decoded whole); the mailbox keeps the newest
``keep`` and lets older ones fall out, so a consumer slower than the camera never builds up lag (the trap of a
plain queue: PyAV's users see the delay grow without bound). Frames are converted to BGR and JPEG only when a set
uses them, once each.
"""
from __future__ import annotations

import collections
import threading
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np


@dataclass(eq=False)
class Frame:
    """One decoded frame of camera ``camera`` (rig index): ``picture`` is an ``av.VideoFrame`` or an (H, W, 3) uint8
    BGR array; ``capture`` and ``arrival`` in seconds since the Unix epoch; ``number`` counts the camera's frames."""

    camera: int
    picture: Any
    capture: float
    arrival: float
    number: int
    _bgr: np.ndarray | None = field(default=None, repr=False)
    _jpeg: tuple[int, bytes] | None = field(default=None, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def bgr(self) -> np.ndarray:
        """The picture as (H, W, 3) uint8 BGR (converted once)."""
        with self._lock:
            if self._bgr is None:
                self._bgr = self.picture if isinstance(self.picture, np.ndarray) else self.picture.to_ndarray(format="bgr24")
                self.picture = None  # the decoder's buffer goes back to its pool
            return self._bgr

    def jpeg(self, quality: int) -> bytes:
        """The picture as a JPEG at ``quality`` (encoded once per quality)."""
        image = self.bgr()
        with self._lock:
            if self._jpeg is None or self._jpeg[0] != quality:
                ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
                if not ok:
                    raise ValueError(f"camera {self.camera}: the frame could not be encoded as JPEG")
                self._jpeg = (quality, data.tobytes())
            return self._jpeg[1]


class FrameMailbox:
    """The newest ``keep`` frames of one camera (thread-safe: one reader puts, the assembler looks)."""

    def __init__(self, keep: int = 8) -> None:
        self._frames: collections.deque[Frame] = collections.deque(maxlen=keep)
        self._lock = threading.Lock()
        self.received = 0

    def put(self, frame: Frame) -> None:
        with self._lock:
            self._frames.append(frame)
            self.received += 1

    def recent(self) -> list[Frame]:
        """The frames kept, oldest first."""
        with self._lock:
            return list(self._frames)

    def newest(self) -> Frame | None:
        with self._lock:
            return self._frames[-1] if self._frames else None
