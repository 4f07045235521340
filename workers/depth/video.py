"""Depth maps as real coded video: H.264 (libx264) and HEVC (libx265) through PyAV.

A 3D-video system codes its depth maps as the luma of an ordinary 8-bit 4:2:0 video with constant
(mid-grey, 128) chroma; the decoder hands the luma plane back to the post-filter. This module does
both sides:

- :func:`encode_depth_frames` codes (H, W) uint8 depth frames at a constant QP and returns the
  elementary stream (Annex B for H.264, HEVC byte stream), so ``8 * len(bytes)`` is the rate in bits.
  Odd sizes are padded by edge replication to even ones (4:2:0 needs them) and cropped on decoding.
- :func:`decode_depth_video` reads the luma planes of a coded depth video (any container FFmpeg
  demuxes: raw .264/.265, MP4, MKV) as (H, W) uint8, exactly as decoded (no range conversion),
  refusing what is not an 8-bit H.264/HEVC video and enforcing frame and pixel limits.
- :func:`probe_depth_video` checks those properties from the headers and packets without decoding.

QP: the constant quantisation parameter of every frame (``ipratio=1``, so intra frames use it too,
as the QP of the common test conditions does).
"""
from __future__ import annotations

import io
import re
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Iterator, Sequence

import av
import cv2
import numpy as np

from workers.common import images

from .errors import CorruptVideo, DepthInputError, NotAVideo, TooManyFrames, UnsupportedVideo

CODECS = {"h264": ("libx264", "h264"), "hevc": ("libx265", "hevc")}
"""codec name -> (PyAV encoder, raw elementary-stream muxer)."""
ACCEPTED_DECODERS = ("h264", "hevc")
EIGHT_BIT_FORMATS = ("yuv420p", "yuvj420p", "yuv422p", "yuvj422p", "yuv444p", "yuvj444p", "gray", "nv12")
MAX_QP = 51


@dataclass(frozen=True)
class DepthVideoInfo:
    """What a coded depth video holds: ``codec`` ("h264"/"hevc"), ``width`` x ``height`` pixels,
    ``frames`` (counted from the packets), ``pix_fmt`` (FFmpeg's name, 8-bit)."""

    codec: str
    width: int
    height: int
    frames: int
    pix_fmt: str


def check_codec(codec: str) -> tuple[str, str]:
    """(encoder, muxer) of ``codec`` ("h264" or "hevc"); DepthInputError when PyAV cannot encode it."""
    if codec not in CODECS:
        raise DepthInputError(f"unknown codec {codec!r}; expected one of {', '.join(CODECS)}")
    encoder, muxer = CODECS[codec]
    try:
        av.codec.Codec(encoder, "w")
    except (av.error.FFmpegError, ValueError):  # pragma: no cover - depends on the PyAV build
        raise DepthInputError(f"this PyAV build has no {encoder} encoder") from None
    return encoder, muxer


def available_codecs() -> list[str]:
    """The codecs of :data:`CODECS` this PyAV build can encode."""
    out = []
    for name in CODECS:
        try:
            check_codec(name)
        except DepthInputError:  # pragma: no cover - depends on the PyAV build
            continue
        out.append(name)
    return out


def _encoder_options(codec: str, qp: int) -> dict[str, str]:
    if codec == "h264":
        return {"qp": str(qp), "x264-params": "ipratio=1:pbratio=1"}
    return {"qp": str(qp), "x265-params": "ipratio=1:pbratio=1:log-level=error:info=0"}


def _padded(frame: np.ndarray) -> np.ndarray:
    """(H, W) uint8 padded by edge replication to even sides."""
    h, w = frame.shape
    return np.pad(frame, ((0, h % 2), (0, w % 2)), mode="edge")


def encode_depth_frames(
    frames: Sequence[np.ndarray], codec: str = "h264", qp: int = 27, preset: str = "medium", gop: int = 1,
) -> bytes:
    """Code 8-bit depth frames as the luma of a 4:2:0 video with chroma 128, at a constant QP.

    frames: (H, W) uint8, all the same size. codec: "h264" or "hevc". qp: 0..51. preset: the
    encoder's speed preset. gop: frames per intra period (1: all intra). Returns the raw
    elementary stream (bytes); its length in bits is the coded rate.
    """
    if not frames:
        raise DepthInputError("no frames to encode")
    if not 0 <= int(qp) <= MAX_QP:
        raise DepthInputError(f"qp must be 0..{MAX_QP}, got {qp}")
    shape = frames[0].shape
    if any(f.dtype != np.uint8 or f.ndim != 2 or f.shape != shape for f in frames):
        raise DepthInputError("frames must all be (H, W) uint8 of the same size")
    encoder, muxer = check_codec(codec)
    ph, pw = _padded(frames[0]).shape
    buf = io.BytesIO()
    with av.open(buf, "w", format=muxer) as out:
        stream = out.add_stream(encoder, rate=25)
        stream.width, stream.height, stream.pix_fmt = pw, ph, "yuv420p"
        stream.gop_size = max(1, int(gop))
        stream.codec_context.thread_count = 1  # one slice per frame, deterministic output
        stream.options = {**_encoder_options(codec, int(qp)), "preset": preset}
        for frame in frames:
            out.mux(stream.encode(_video_frame(_padded(frame))))
        out.mux(stream.encode())
    return buf.getvalue()


def encode_texture_frames(
    frames: Sequence[np.ndarray], codec: str = "h264", qp: int = 27, preset: str = "medium", gop: int = 1,
) -> bytes:
    """Code BGR texture frames (H, W, 3) uint8 (even H and W) as 4:2:0 video at a constant QP;
    returns the elementary stream, like :func:`encode_depth_frames`."""
    if not frames or any(f.dtype != np.uint8 or f.ndim != 3 or f.shape != frames[0].shape for f in frames):
        raise DepthInputError("texture frames must all be (H, W, 3) uint8 of the same size")
    h, w = frames[0].shape[:2]
    if h % 2 or w % 2:
        raise DepthInputError(f"a 4:2:0 texture needs an even width and height, got {w}x{h}")
    if not 0 <= int(qp) <= MAX_QP:
        raise DepthInputError(f"qp must be 0..{MAX_QP}, got {qp}")
    encoder, muxer = check_codec(codec)
    buf = io.BytesIO()
    with av.open(buf, "w", format=muxer) as out:
        stream = out.add_stream(encoder, rate=25)
        stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
        stream.gop_size = max(1, int(gop))
        stream.codec_context.thread_count = 1
        stream.options = {**_encoder_options(codec, int(qp)), "preset": preset}
        for frame in frames:
            yuv = cv2.cvtColor(frame, cv2.COLOR_BGR2YUV_I420)
            out.mux(stream.encode(av.VideoFrame.from_ndarray(yuv, format="yuv420p")))
        out.mux(stream.encode())
    return buf.getvalue()


def code_texture(frames: Sequence[np.ndarray], codec: str, qp: int, preset: str = "medium") -> tuple[list[np.ndarray], int]:
    """Encode and decode textures (H, W, 3) uint8 BGR of any size (odd sides padded by edge
    replication, then cropped): (decoded BGR frames, rate in bits without SEI)."""
    h, w = frames[0].shape[:2]
    padded = [np.pad(f, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge") for f in frames]
    stream = encode_texture_frames(padded, codec, qp, preset)
    out = []
    with _open(stream, "texture") as container:
        for frame in container.decode(container.streams.video[0]):
            yuv = frame.to_ndarray(format="yuv420p")
            out.append(np.ascontiguousarray(cv2.cvtColor(yuv, cv2.COLOR_YUV2BGR_I420)[:h, :w]))
    return out, coded_bits(stream, codec)


def _video_frame(luma: np.ndarray) -> av.VideoFrame:
    """A yuv420p frame with ``luma`` (even H, W) as Y and 128 as U and V."""
    h, w = luma.shape
    yuv = np.full((h * 3 // 2, w), 128, np.uint8)
    yuv[:h] = luma
    return av.VideoFrame.from_ndarray(yuv, format="yuv420p")


def luma_plane(frame: av.VideoFrame) -> np.ndarray:
    """The decoded luma plane (H, W) uint8 of an 8-bit frame, as stored (no range conversion)."""
    plane = frame.planes[0]
    rows = np.frombuffer(plane, np.uint8).reshape(frame.height, plane.line_size)
    return np.ascontiguousarray(rows[:, :frame.width])


def _open(source: str | Path | BinaryIO | bytes, name: str) -> av.container.InputContainer:
    if isinstance(source, (bytes, bytearray)):
        source = io.BytesIO(source)
    try:
        return av.open(source if not isinstance(source, Path) else str(source), "r")
    except (av.error.FFmpegError, OSError, UnicodeDecodeError, ValueError):
        raise NotAVideo(f"{name} is not a video file that can be read (expected H.264 or HEVC)") from None


def _check_stream(stream: av.video.stream.VideoStream, name: str, max_pixels: int | None) -> tuple[str, int, int, str]:
    ctx = stream.codec_context
    codec, width, height = ctx.name, int(ctx.width), int(ctx.height)
    pix_fmt = ctx.pix_fmt or ""
    if codec not in ACCEPTED_DECODERS:
        raise UnsupportedVideo(f"{name} is coded with {codec}; depth videos must be H.264 or HEVC")
    if pix_fmt and pix_fmt not in EIGHT_BIT_FORMATS:
        raise UnsupportedVideo(f"{name} has {pix_fmt} samples; depth videos must be 8-bit "
                               f"({', '.join(EIGHT_BIT_FORMATS[:3])}, ...)")
    if width <= 0 or height <= 0:
        raise CorruptVideo(f"{name} does not state its frame size")
    if max_pixels is not None:
        images.check_pixels(width, height, max_pixels, f"each frame of {name}")
    return codec, width, height, pix_fmt


def probe_depth_video(
    source: str | Path | BinaryIO | bytes, max_frames: int | None = None, max_pixels: int | None = None,
    name: str = "depth video",
) -> DepthVideoInfo:
    """Check a coded depth video without decoding it: one video stream, H.264/HEVC, 8-bit samples,
    at most ``max_pixels`` per frame and ``max_frames`` frames (counted from the packets).

    Raises NotAVideo, UnsupportedVideo, TooManyPixels (:mod:`workers.common.images`), TooManyFrames,
    CorruptVideo (:mod:`workers.depth.errors`).
    """
    with _open(source, name) as container:
        stream = _video_stream(container, name)
        codec, width, height, pix_fmt = _check_stream(stream, name, max_pixels)
        frames = 0
        try:
            for packet in container.demux(stream):
                if packet.size > 0:
                    frames += 1
                    _check_frame_count(frames, max_frames, name)
        except av.error.FFmpegError as exc:
            raise CorruptVideo(f"{name} is damaged: {exc}") from None
    if frames == 0:
        raise CorruptVideo(f"{name} holds no frames")
    return DepthVideoInfo(codec, width, height, frames, pix_fmt)


def _video_stream(container, name: str):
    """The first video stream of an open container (NotAVideo when none)."""
    if not container.streams.video:
        raise NotAVideo(f"{name} has no video stream")
    return container.streams.video[0]


def _check_frame_count(count: int, max_frames: int | None, name: str) -> None:
    if max_frames is not None and count > max_frames:
        raise TooManyFrames(f"{name} has more than {max_frames} frames, the limit")


def decode_depth_video(
    source: str | Path | BinaryIO | bytes, max_frames: int | None = None, max_pixels: int | None = None,
    name: str = "depth video", crop: tuple[int, int] | None = None,
) -> Iterator[np.ndarray]:
    """Yield the luma planes (H, W) uint8 of a coded depth video, frame by frame.

    max_frames / max_pixels: limits (TooManyFrames / TooManyPixels).
    crop: (width, height) to cut each frame to (the size before :func:`encode_depth_frames` padded
    it). A frame whose size or sample format differs from the first one's, or a decoding error,
    raises CorruptVideo.
    """
    with _open(source, name) as container:
        stream = _video_stream(container, name)
        _, width, height, _ = _check_stream(stream, name, max_pixels)
        count = 0
        try:
            for frame in container.decode(stream):
                count += 1
                _check_frame_count(count, max_frames, name)
                if (frame.width, frame.height) != (width, height) or frame.format.name not in EIGHT_BIT_FORMATS:
                    raise CorruptVideo(f"{name}: frame {count - 1} is {frame.width}x{frame.height} "
                                          f"{frame.format.name}, expected {width}x{height} 8-bit")
                luma = luma_plane(frame)
                yield luma if crop is None else np.ascontiguousarray(luma[:crop[1], :crop[0]])
        except av.error.FFmpegError as exc:
            raise CorruptVideo(f"{name}: decoding failed after {count} frames: {exc}") from None
    if count == 0:
        raise CorruptVideo(f"{name} holds no decodable frame")


def nal_units(stream: bytes) -> list[bytes]:
    """The NAL units of an Annex B byte stream (start codes removed)."""
    starts = [m.end() for m in re.finditer(b"\x00\x00\x01", stream)]
    units = []
    for i, start in enumerate(starts):
        end = starts[i + 1] - 3 if i + 1 < len(starts) else len(stream)
        units.append(stream[start:end].rstrip(b"\x00") if i + 1 < len(starts) else stream[start:end])
    return units


def _is_sei(unit: bytes, codec: str) -> bool:
    if not unit:
        return False
    if codec == "h264":
        return unit[0] & 0x1F == 6
    return (unit[0] >> 1) & 0x3F in (39, 40)


def coded_bits(stream: bytes, codec: str) -> int:
    """Rate of an Annex B stream in bits, without its SEI messages (libx264 writes its whole
    configuration as a ~600-byte SEI that a real 3D-video bitstream would not carry)."""
    return 8 * sum(len(u) + 3 for u in nal_units(stream) if not _is_sei(u, codec))


def code_depth(frames: Sequence[np.ndarray], codec: str, qp: int, preset: str = "medium") -> tuple[list[np.ndarray], int]:
    """Encode and decode: (decoded frames (H, W) uint8 cropped to the input size, rate in bits
    without SEI, see :func:`coded_bits`)."""
    stream = encode_depth_frames(frames, codec, qp, preset)
    h, w = frames[0].shape
    return list(decode_depth_video(stream, crop=(w, h))), coded_bits(stream, codec)
