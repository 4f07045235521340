"""Video files with PyAV: probe (frames, size, rate), decode to BGR frames, write H.264 MP4."""
from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import BinaryIO, Iterator

import av
import numpy as np


class VideoError(ValueError):
    """A file that is not a readable video (the message says why)."""


@dataclass(frozen=True)
class VideoInfo:
    """What a video's container says: ``frames`` (counted by demuxing when the header has no
    count), ``width`` x ``height`` pixels, ``fps`` frames per second, ``codec`` name."""

    frames: int
    width: int
    height: int
    fps: float
    codec: str


def probe_video(source: str | Path | BinaryIO) -> VideoInfo:
    """Read a video's frame count, size and rate without decoding its pictures."""
    try:
        with av.open(source, mode="r") as container:
            if not container.streams.video:
                raise VideoError("has no video stream")
            stream = container.streams.video[0]
            rate = stream.average_rate or stream.guessed_rate or stream.base_rate
            frames = stream.frames or sum(1 for p in container.demux(stream) if p.size > 0)
            return VideoInfo(int(frames), int(stream.codec_context.width), int(stream.codec_context.height),
                             float(rate) if rate else 0.0, stream.codec_context.name)
    except av.FFmpegError as exc:
        raise VideoError(f"is not a readable video ({exc})") from None


def decode_frames(source: str | Path | BinaryIO) -> Iterator[np.ndarray]:
    """The video's frames in order, each (H, W, 3) uint8 BGR."""
    try:
        with av.open(source, mode="r") as container:
            if not container.streams.video:
                raise VideoError("has no video stream")
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"
            for frame in container.decode(stream):
                yield frame.to_ndarray(format="bgr24")
    except av.FFmpegError as exc:
        raise VideoError(f"could not be decoded ({exc})") from None


class H264Writer:
    """Write BGR frames (H, W, 3) uint8 to an H.264 MP4 (libx264, yuv420p: even sizes)."""

    def __init__(self, path: str | Path, width: int, height: int, fps: float, crf: int = 20,
                 preset: str = "veryfast") -> None:
        if width % 2 or height % 2:
            raise ValueError(f"H.264 in yuv420p needs an even size, got {width}x{height}")
        self._container = av.open(str(path), mode="w", format="mp4")
        rate = Fraction(fps).limit_denominator(1001)
        self._stream = self._container.add_stream("libx264", rate=rate)
        self._stream.width, self._stream.height = width, height
        self._stream.pix_fmt = "yuv420p"
        self._stream.options = {"crf": str(crf), "preset": preset}
        self.frames = 0

    def write(self, image: np.ndarray) -> None:
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="bgr24")
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        self.frames += 1

    def close(self) -> None:
        for packet in self._stream.encode():
            self._container.mux(packet)
        self._container.close()

    def __enter__(self) -> "H264Writer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
