"""Depth maps as coded H.264/HEVC video through PyAV: round trips, rates, validation."""
import io

import av
import numpy as np
import pytest

from workers.common.errors import InputError
from workers.common.images import TooManyPixels
from workers.depth.errors import DepthInputError
from workers.depth.video import (
    available_codecs, code_depth, code_texture, coded_bits, decode_depth_video, encode_depth_frames,
    nal_units, probe_depth_video,
)


def disc_depth(h=36, w=50, shift=0):
    y, x = np.mgrid[:h, :w]
    return np.where((x - 20 - shift) ** 2 + (y - 18) ** 2 < 100, 200, 60).astype(np.uint8)


def noisy_depth(h=48, w=64, seed=0):
    rng = np.random.default_rng(seed)
    return np.clip(disc_depth(h, w).astype(int) + rng.integers(-20, 21, (h, w)), 0, 255).astype(np.uint8)


def test_h264_at_qp_0_is_lossless_and_odd_sizes_are_cropped_back():
    frames = [noisy_depth(35, 49, s) for s in range(3)]
    decoded, bits = code_depth(frames, "h264", 0)
    assert len(decoded) == 3 and bits > 0
    for got, want in zip(decoded, frames):
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("codec", available_codecs())
def test_rate_falls_and_error_grows_with_qp(codec):
    frame = noisy_depth()
    results = [code_depth([frame], codec, qp) for qp in (22, 32, 42)]
    rates = [bits for _, bits in results]
    errors = [np.abs(dec[0].astype(int) - frame).mean() for dec, _ in results]
    assert rates[0] > rates[1] > rates[2]
    assert errors[0] < errors[1] < errors[2]


def test_sei_messages_are_not_counted_as_rate():
    stream = encode_depth_frames([disc_depth()], "h264", 30)
    kinds = [u[0] & 0x1F for u in nal_units(stream)]
    assert 6 in kinds and 5 in kinds  # libx264 writes its settings as SEI; 5 = IDR slice
    sei = sum(len(u) + 3 for u in nal_units(stream) if u[0] & 0x1F == 6)
    assert coded_bits(stream, "h264") == 8 * (sum(len(u) + 3 for u in nal_units(stream)) - sei)


def mp4_depth_video(frames) -> bytes:
    """Frames (H, W) uint8 as the luma of a lossless (QP 0) H.264 MP4 with chroma 128."""
    h, w = frames[0].shape
    buf = io.BytesIO()
    with av.open(buf, "w", format="mp4") as out:
        s = out.add_stream("libx264", rate=25)
        s.width, s.height, s.pix_fmt = w, h, "yuv420p"
        s.options = {"qp": "0"}
        for f in frames:
            yuv = np.vstack([f, np.full((h // 2, w), 128, np.uint8)])
            out.mux(s.encode(av.VideoFrame.from_ndarray(yuv, format="yuv420p")))
        out.mux(s.encode())
    return buf.getvalue()


def test_probe_and_decode_an_mp4_with_several_frames():
    frames = [disc_depth(shift=s) for s in range(4)]
    buf = io.BytesIO(mp4_depth_video(frames))
    info = probe_depth_video(buf.getvalue())
    assert (info.codec, info.width, info.height, info.frames, info.pix_fmt) == ("h264", 50, 36, 4, "yuv420p")
    decoded = list(decode_depth_video(buf.getvalue()))
    for got, want in zip(decoded, frames):
        np.testing.assert_array_equal(got, want)


def test_texture_round_trip_keeps_the_size():
    rng = np.random.default_rng(1)
    tex = rng.integers(0, 256, (21, 33, 3), dtype=np.uint8)
    decoded, bits = code_texture([tex], "h264", 22)
    assert decoded[0].shape == tex.shape and bits > 0


def mpeg4_video(w=32, h=32, n=2) -> bytes:
    buf = io.BytesIO()
    with av.open(buf, "w", format="avi") as out:
        s = out.add_stream("mpeg4", rate=25)
        s.width, s.height, s.pix_fmt = w, h, "yuv420p"
        for _ in range(n):
            out.mux(s.encode(av.VideoFrame.from_ndarray(np.zeros((h * 3 // 2, w), np.uint8), format="yuv420p")))
        out.mux(s.encode())
    return buf.getvalue()


@pytest.mark.parametrize("data,kwargs,code", [
    (b"this is not a video at all" * 10, {}, "not_a_video"),
    (mpeg4_video(), {}, "unsupported_format"),
])
def test_probe_refuses_what_is_not_an_8_bit_h264_or_hevc_video(data, kwargs, code):
    with pytest.raises(InputError) as err:
        probe_depth_video(data, **kwargs)
    assert err.value.code == code


def test_frame_and_pixel_limits():
    data = encode_depth_frames([disc_depth()] * 3, "h264", 30)
    with pytest.raises(DepthInputError, match="more than 2 frames") as err:
        probe_depth_video(data, max_frames=2)
    assert err.value.code == "too_many_frames"
    with pytest.raises(TooManyPixels, match="the limit is 1,000") as err:
        probe_depth_video(data, max_pixels=1000)
    assert err.value.code == "too_many_pixels"
    with pytest.raises(DepthInputError) as err:
        list(decode_depth_video(data, max_frames=2))
    assert err.value.code == "too_many_frames"


def test_encoder_input_checks():
    with pytest.raises(DepthInputError, match="qp"):
        encode_depth_frames([disc_depth()], "h264", 52)
    with pytest.raises(DepthInputError, match="unknown codec"):
        encode_depth_frames([disc_depth()], "vp9", 30)
    with pytest.raises(DepthInputError, match="same size"):
        encode_depth_frames([disc_depth(), disc_depth(20, 20)], "h264", 30)
