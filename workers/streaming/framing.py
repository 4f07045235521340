"""Binary WebSocket messages: a small JSON header followed by a payload.

Layout of every binary message, in both directions::

    bytes 0..3      N, the header length: unsigned 32-bit big-endian
    bytes 4..4+N    the header: a UTF-8 JSON object
    the rest        the payload

A live frame set (client -> server on ``/v1/rigs/{id}/live``) carries one JPEG per camera; its
header lists their byte lengths in payload order: ``{"sizes": [n0, n1, ...], "cameras": [...]
(optional: camera names in payload order, default rig order), "background": false, "seq": 7}``, and from a
client that knows when its frames were taken (``sweepcast live``) ``"captured": [t0, t1, ...]`` (each frame's
capture time, seconds since the Unix epoch, payload order), ``"stale": [names]`` (cameras whose frame is not of
this instant: a camera gone missing; left out of the render) and ``"tolerance"`` (the largest spread of capture
times the client allowed, seconds).
A rendered frame (server -> client on ``/v1/rigs/{id}/view``) carries one JPEG and the header
``{"type": "frame", ...}`` described in :mod:`workers.streaming.session`.
"""
from __future__ import annotations

import json
import struct
import math
from dataclasses import dataclass, field
from typing import Any, Sequence

MAX_HEADER_BYTES = 64 * 1024
_LEN = struct.Struct(">I")


class FramingError(ValueError):
    """A binary message that does not follow the layout above; the message says what is wrong."""


def pack_message(header: dict[str, Any], payloads: Sequence[bytes] = ()) -> bytes:
    """One binary message: the header (a JSON-able dict) then the payloads concatenated."""
    head = json.dumps(header, separators=(",", ":"), allow_nan=False).encode()
    return b"".join([_LEN.pack(len(head)), head, *payloads])


def unpack_message(data: bytes) -> tuple[dict[str, Any], memoryview]:
    """(header dict, payload view) of a binary message; FramingError when malformed."""
    if len(data) < _LEN.size:
        raise FramingError(f"a binary message starts with a 4-byte header length; got {len(data)} bytes")
    (n,) = _LEN.unpack_from(data)
    if n > MAX_HEADER_BYTES:
        raise FramingError(f"header length {n} is over the limit of {MAX_HEADER_BYTES} bytes")
    if _LEN.size + n > len(data):
        raise FramingError(f"header length {n} runs past the end of the {len(data)}-byte message")
    try:
        header = json.loads(bytes(data[_LEN.size:_LEN.size + n]).decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FramingError(f"the header is not UTF-8 JSON: {exc}") from None
    except RecursionError:  # "[[[[..." within the size limit: the parser gives up, the socket must not
        raise FramingError("the header is nested too deeply to parse") from None
    if not isinstance(header, dict):
        raise FramingError("the header must be a JSON object")
    return header, memoryview(data)[_LEN.size + n:]


@dataclass(frozen=True)
class FrameSet:
    """A parsed live frame set: ``jpegs`` in rig camera order, plus the header's flags; ``captured`` (s since the
    epoch, rig order) or None when the client sent no capture times; ``stale`` (rig order); ``tolerance`` (s) or
    None."""

    jpegs: list[bytes]
    background: bool
    seq: int | None
    header: dict[str, Any]
    captured: list[float] | None = None
    stale: list[bool] = field(default_factory=list)
    tolerance: float | None = None


def unpack_frame_set(data: bytes, camera_names: Sequence[str]) -> FrameSet:
    """Split a live frame-set message into one JPEG per rig camera (in rig order).

    Checks the counts and sizes only; whether each JPEG decodes is the session's job.
    FramingError names the problem (wrong number of images, sizes not adding up, unknown camera).
    """
    header, payload = unpack_message(data)
    sizes = header.get("sizes")
    n = len(camera_names)
    if not isinstance(sizes, list) or not all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in sizes):
        raise FramingError("the header needs 'sizes': the byte length of each JPEG, positive integers")
    if len(sizes) != n:
        raise FramingError(f"the frame set holds {len(sizes)} images; the rig has {n} cameras")
    if sum(sizes) != len(payload):
        raise FramingError(f"'sizes' add up to {sum(sizes)} bytes but the payload has {len(payload)}")
    order = _camera_order(header.get("cameras"), camera_names)
    parts: list[bytes] = [b""] * n
    offset = 0
    for slot, size in zip(order, sizes):
        parts[slot] = bytes(payload[offset:offset + size])
        offset += size
    background = header.get("background", False)
    if not isinstance(background, bool):
        raise FramingError("'background' must be true or false")
    seq = header.get("seq")
    if seq is not None and (not isinstance(seq, int) or isinstance(seq, bool)):
        raise FramingError("'seq' must be an integer")
    captured = _captured(header.get("captured"), order, n)
    stale = _stale(header.get("stale"), camera_names)
    tolerance = header.get("tolerance")
    if tolerance is not None and (not _number(tolerance) or tolerance <= 0):
        raise FramingError("'tolerance' must be a positive number of seconds")
    if len(stale) - sum(stale) < 2 and any(stale):
        raise FramingError("a frame set needs at least two cameras that are not stale")
    return FrameSet(parts, background, seq, header, captured, stale, tolerance)


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _captured(values: Any, order: list[int], n: int) -> list[float] | None:
    """The header's capture times in rig order (None when absent); FramingError when malformed."""
    if values is None:
        return None
    if not isinstance(values, list) or len(values) != n or not all(_number(v) for v in values):
        raise FramingError(f"'captured' must list {n} capture times (seconds since the Unix epoch), one per image")
    out = [0.0] * n
    for slot, value in zip(order, values):
        out[slot] = float(value)
    return out


def _stale(names: Any, camera_names: Sequence[str]) -> list[bool]:
    """Per rig camera: named in the header's 'stale'; FramingError for a name the rig does not have."""
    if names is None:
        return [False] * len(camera_names)
    if not isinstance(names, list) or not all(isinstance(x, str) for x in names):
        raise FramingError("'stale' must list camera names")
    unknown = sorted(set(names) - set(camera_names))
    if unknown:
        raise FramingError(f"'stale' names unknown camera(s) {', '.join(unknown)}; the rig has {', '.join(camera_names)}")
    return [name in names for name in camera_names]


def _camera_order(names: Any, camera_names: Sequence[str]) -> list[int]:
    """Rig index of each payload image: the header's 'cameras' (names) or rig order."""
    if names is None:
        return list(range(len(camera_names)))
    if not isinstance(names, list) or sorted(map(str, names)) != sorted(camera_names):
        raise FramingError(f"'cameras' must name each rig camera once: {', '.join(camera_names)}")
    index = {name: i for i, name in enumerate(camera_names)}
    return [index[str(name)] for name in names]
