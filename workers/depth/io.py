"""Reading and writing depth maps, textures, raw YUV depth sequences and MPEG camera files.

- Depth images: PNG (8/16-bit) and PGM (P5, 8/16-bit), single channel. A 3-channel image whose
  channels are equal (a grey depth saved as colour) is accepted as its first channel.
- Raw YUV: planar frames, 8-bit samples or little-endian 16-bit samples for 9..16 bits;
  4:0:0 (luma only) or 4:2:0 (luma + two quarter-size chroma planes, ignored on reading and
  written as mid-grey). The frame count must divide the file size exactly.
- MPEG camera parameter files (VSRS/DERS): per camera a name, the 3x3 intrinsic matrix, two
  distortion values (ignored, as VSRS does), and the 3x4 extrinsic [R | T] that gives the camera's
  orientation and position in the world (camera to world: X_w = R X_c + T), optionally followed by
  a "0 0 0 1" row. Converted to our world-to-camera convention: R' = R^T, t' = -R^T T.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Iterator, Sequence

import cv2
import numpy as np

from workers.camera import Camera, CameraError
from workers.common import images

from .errors import DepthInputError, PartialFrames, TooManyFrames
from .levels import check_bits, check_levels, level_dtype

CHROMA_FORMATS = ("400", "420")


def decode_image_checked(data: bytes, flags: int, what: str, max_pixels: int | None = None) -> np.ndarray:
    """:func:`workers.common.images.decode_image` (header size checked against ``max_pixels``, None:
    the process's limit, before decoding) with its errors naming ``what``."""
    try:
        return images.decode_image(data, flags, max_pixels)
    except images.ImageInputError as exc:
        raise exc.about(what) from None


def decode_depth(data: bytes, bits: int | None = None, max_pixels: int | None = None) -> tuple[np.ndarray, int]:
    """PNG/PGM bytes -> (levels (H, W) uint8/uint16, bit depth).

    bits: the expected bit depth (8..16); None takes 8 or 16 from the file. A file whose sample
    size does not match ``bits`` raises DepthInputError; an image over ``max_pixels`` (width x height; None: the
    process's limit), refused before decoding, or one that does not decode raises the decoder's
    :class:`~workers.common.images.ImageInputError` naming the depth map.
    """
    img = decode_image_checked(data, cv2.IMREAD_UNCHANGED | cv2.IMREAD_IGNORE_ORIENTATION, "depth map", max_pixels)
    if img.ndim == 3:
        if img.shape[2] == 3 and (img == img[..., :1]).all():
            img = np.ascontiguousarray(img[..., 0])
        else:
            raise DepthInputError(f"depth map must be a single-channel (grey) image, got {img.shape[2]} channels")
    if img.dtype not in (np.uint8, np.uint16):
        raise DepthInputError(f"depth map must have 8- or 16-bit samples, got {img.dtype}")
    file_bits = 8 if img.dtype == np.uint8 else 16
    if bits is None:
        return img, file_bits
    check_bits(bits)
    if level_dtype(bits) != img.dtype:
        raise DepthInputError(
            f"expected a {bits}-bit depth map ({'8' if bits == 8 else '16'}-bit samples) but the image has "
            f"{file_bits}-bit samples"
        )
    return check_levels(img, bits), bits


def encode_depth(depth: np.ndarray, fmt: str = "png") -> bytes:
    """Depth levels (H, W) uint8/uint16 -> PNG or PGM bytes (lossless)."""
    if fmt not in ("png", "pgm"):
        raise DepthInputError(f"depth format must be png or pgm, got {fmt!r}")
    if depth.ndim != 2 or depth.dtype not in (np.uint8, np.uint16):
        raise DepthInputError(f"depth map must be (H, W) uint8/uint16, got {depth.dtype} {depth.shape}")
    ok, buf = cv2.imencode("." + fmt, depth)
    if not ok:  # pragma: no cover - OpenCV encodes every uint8/uint16 grey image
        raise RuntimeError(f"OpenCV failed to encode a {fmt} image")
    return buf.tobytes()


def decode_texture(data: bytes, max_pixels: int | None = None) -> np.ndarray:
    """Image bytes -> (H, W, 3) uint8 BGR, stored pixels (EXIF orientation ignored so it stays
    aligned with its depth map); over ``max_pixels`` (None: the process's limit) it is refused undecoded."""
    return decode_image_checked(data, cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION, "texture", max_pixels)


def read_depth(path: str | Path, bits: int | None = None) -> tuple[np.ndarray, int]:
    """Read a PNG/PGM depth file; see :func:`decode_depth`."""
    return decode_depth(Path(path).read_bytes(), bits)


def write_depth(path: str | Path, depth: np.ndarray) -> None:
    """Write depth levels as PNG or PGM, chosen by the file suffix."""
    path = Path(path)
    path.write_bytes(encode_depth(depth, path.suffix.lower().lstrip(".") or "png"))


@dataclass(frozen=True)
class YuvFormat:
    """Layout of a raw planar YUV depth sequence: size in pixels, bit depth, "400" or "420"."""

    width: int
    height: int
    bits: int = 8
    chroma: str = "400"

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise DepthInputError(f"YUV width and height must be positive, got {self.width}x{self.height}")
        check_bits(self.bits)
        if self.chroma not in CHROMA_FORMATS:
            raise DepthInputError(f"chroma format must be one of {', '.join(CHROMA_FORMATS)}, got {self.chroma!r}")

    @property
    def sample_bytes(self) -> int:
        return 1 if self.bits == 8 else 2

    @property
    def chroma_samples(self) -> int:
        """Samples in both chroma planes of one frame (0 for 4:0:0)."""
        return 0 if self.chroma == "400" else 2 * ((self.width + 1) // 2) * ((self.height + 1) // 2)

    @property
    def frame_bytes(self) -> int:
        return (self.width * self.height + self.chroma_samples) * self.sample_bytes

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(np.uint8) if self.bits == 8 else np.dtype("<u2")


def yuv_frame_count(file_size: int, fmt: YuvFormat) -> int:
    """Frames in a file of ``file_size`` bytes; PartialFrames unless it is a positive whole number."""
    frames, rest = divmod(file_size, fmt.frame_bytes)
    if rest or frames == 0:
        raise PartialFrames(
            f"YUV file has {file_size} bytes, which is not a whole number of {fmt.width}x{fmt.height} "
            f"{fmt.bits}-bit {':'.join(fmt.chroma)} frames ({fmt.frame_bytes} bytes each)"
        )
    return frames


def yuv_sequence_frames(file_size: int, fmt: YuvFormat, max_frames: int, name: str = "the sequence") -> int:
    """Frames of a raw YUV depth sequence of ``file_size`` bytes, the one rule of the upload route and the job:
    PartialFrames unless a positive whole number of ``fmt`` frames, TooManyFrames past ``max_frames``; messages name
    the file (``name``)."""
    try:
        count = yuv_frame_count(file_size, fmt)
    except PartialFrames as exc:
        raise exc.about(name) from None
    if count > max_frames:
        raise TooManyFrames(f"{name} holds {count} frames; the limit is {max_frames}")
    return count


def read_yuv_frames(fh: BinaryIO, fmt: YuvFormat, count: int) -> Iterator[np.ndarray]:
    """Yield ``count`` luma planes (H, W) uint8/uint16 from an open file, checking their levels."""
    luma_bytes = fmt.width * fmt.height * fmt.sample_bytes
    for index in range(count):
        frame = fh.read(fmt.frame_bytes)
        if len(frame) != fmt.frame_bytes:
            raise DepthInputError(f"YUV file ended inside frame {index}")
        luma = np.frombuffer(frame[:luma_bytes], fmt.dtype).reshape(fmt.height, fmt.width)
        luma = luma.astype(level_dtype(fmt.bits))
        check_levels(luma, fmt.bits, f"frame {index}")
        yield luma


def read_yuv(path: str | Path, fmt: YuvFormat) -> np.ndarray:
    """All luma planes of a YUV depth file: (N, H, W) uint8/uint16."""
    path = Path(path)
    count = yuv_frame_count(path.stat().st_size, fmt)
    with path.open("rb") as fh:
        return np.stack(list(read_yuv_frames(fh, fmt, count)))


def write_yuv_frame(fh: BinaryIO, depth: np.ndarray, fmt: YuvFormat) -> None:
    """Append one depth frame (H, W) as planar YUV; 4:2:0 chroma planes are mid-grey."""
    if depth.shape != (fmt.height, fmt.width):
        raise DepthInputError(f"frame is {depth.shape[1]}x{depth.shape[0]}, expected {fmt.width}x{fmt.height}")
    check_levels(depth, fmt.bits)
    fh.write(np.ascontiguousarray(depth, fmt.dtype).tobytes())
    if fmt.chroma_samples:
        fh.write(np.full(fmt.chroma_samples, 1 << (fmt.bits - 1), fmt.dtype).tobytes())


def write_yuv(path: str | Path, frames: Sequence[np.ndarray], fmt: YuvFormat) -> None:
    """Write depth frames (each (H, W)) as a raw YUV file."""
    with Path(path).open("wb") as fh:
        for frame in frames:
            write_yuv_frame(fh, frame, fmt)


def read_texture_yuv_frames(fh: BinaryIO, width: int, height: int, count: int) -> Iterator[np.ndarray]:
    """Yield ``count`` 8-bit 4:2:0 texture frames as (H, W, 3) uint8 BGR (even sizes only)."""
    if width % 2 or height % 2:
        raise DepthInputError(f"a 4:2:0 texture needs an even width and height, got {width}x{height}")
    size = width * height * 3 // 2
    for index in range(count):
        frame = fh.read(size)
        if len(frame) != size:
            raise DepthInputError(f"texture YUV file ended inside frame {index}")
        yuv = np.frombuffer(frame, np.uint8).reshape(height * 3 // 2, width)
        yield cv2.cvtColor(yuv, cv2.COLOR_YUV2BGR_I420)


def parse_mpeg_cameras(text: str, width: int, height: int) -> dict[str, Camera]:
    """MPEG/VSRS camera parameter text -> {name: Camera} (our world-to-camera convention).

    width/height: the image size of every camera (the file does not store it).
    """
    tokens = text.split()
    cams: dict[str, Camera] = {}
    i = 0
    while i < len(tokens):
        name = tokens[i]
        values = tokens[i + 1:i + 24]
        if len(values) < 23:
            raise DepthInputError(f"camera file: camera {name!r} is incomplete (needs 3x3 + 2 + 3x4 numbers)")
        try:
            nums = np.array([float(v) for v in values])
        except ValueError:
            raise DepthInputError(f"camera file: camera {name!r} has a non-numeric value") from None
        i += 24
        if tokens[i:i + 4] and _is_number(tokens[i]):  # optional last extrinsic row "0 0 0 1"
            i += 4
        K, ext = nums[:9].reshape(3, 3), nums[11:].reshape(3, 4)
        R_c2w, centre = ext[:, :3], ext[:, 3]
        try:
            cams[name] = Camera.from_center(name, K, R_c2w.T, centre, width, height)
        except CameraError as exc:
            raise exc.about("camera file") from None
    if not cams:
        raise DepthInputError("camera file holds no camera")
    return cams


def format_mpeg_cameras(cameras: Sequence[Camera]) -> str:
    """Cameras -> MPEG/VSRS camera parameter text (inverse of :func:`parse_mpeg_cameras`)."""
    blocks = []
    for cam in cameras:
        ext = np.hstack([cam.R.T, cam.center[:, None]])
        rows = [cam.name, *(" ".join(f"{v:.10g}" for v in r) for r in cam.K), "0", "0"]
        rows += [" ".join(f"{v:.10g}" for v in r) for r in ext]
        blocks.append("\n".join(rows))
    return "\n\n".join(blocks) + "\n"


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True

