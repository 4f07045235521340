"""The cameras' sources as the user names them: ``SOURCE`` (rig order) or ``NAME=SOURCE``.

- ``rtsp://``, ``rtsps://``, ``rtmp://``, ``http(s)://``, ``udp://``, ``srt://``, ``tcp://`` URLs: network streams,
  read through PyAV (FFmpeg).
- ``/dev/videoN`` or ``v4l2:N``: a V4L2 device (USB cameras on Linux), read through OpenCV's V4L2 backend (the
  FFmpeg inside PyAV's wheels is built without it).
- anything else: a video file, played at its own frame rate (for tests and demos), over and over.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Sequence

NETWORK_SCHEMES = ("rtsp", "rtsps", "rtmp", "rtmps", "http", "https", "udp", "srt", "tcp")
SourceKind = Literal["network", "v4l2", "file"]


class SourceError(ValueError):
    """Sources that cannot be matched to the rig's cameras, or a source that cannot be used (the message says why)."""


@dataclass(frozen=True)
class Source:
    """Where camera ``name`` (rig index ``camera``) comes from: ``target`` is a URL, a device path or a file path."""

    camera: int
    name: str
    kind: SourceKind
    target: str

    @property
    def shown(self) -> str:
        """The target without a password (``rtsp://user:secret@host`` -> ``rtsp://user:***@host``), for messages."""
        return re.sub(r"(://[^:/@]+:)[^@/]+@", r"\1***@", self.target)


def source_kind(target: str) -> SourceKind:
    scheme = target.split("://", 1)[0].lower() if "://" in target else ""
    if scheme in NETWORK_SCHEMES:
        return "network"
    if target.startswith("v4l2:") or re.fullmatch(r"/dev/video\d+", target):
        return "v4l2"
    return "file"


def device_path(target: str) -> str:
    """``v4l2:N`` -> ``/dev/videoN``; a device path as it is."""
    return f"/dev/video{target[5:]}" if target.startswith("v4l2:") else target


def parse_sources(args: Sequence[str], cameras: Sequence[str]) -> list[Source]:
    """One :class:`Source` per rig camera (rig order) from ``args``: all ``NAME=SOURCE`` (any order, each camera
    once) or all plain (rig order, one per camera). SourceError says what does not match."""
    named = [a for a in args if _name_of(a, cameras) is not None]
    if named and len(named) != len(args):
        raise SourceError("give every source as NAME=SOURCE or none: mixing them leaves the order unclear")
    if not named and len(args) != len(cameras):
        raise SourceError(f"the rig has {len(cameras)} cameras ({', '.join(cameras)}); got {len(args)} sources: give "
                          "one per camera in rig order, or NAME=SOURCE")
    if named:
        by_name: dict[str, str] = {}
        for a in args:
            name = _name_of(a, cameras)
            if name in by_name:
                raise SourceError(f"camera {name} is given twice")
            by_name[name] = a[len(name) + 1:]
        absent = [c for c in cameras if c not in by_name]
        if absent:
            raise SourceError(f"no source for camera(s) {', '.join(absent)}")
        targets = [by_name[c] for c in cameras]
    else:
        targets = list(args)
    sources = []
    for i, (name, target) in enumerate(zip(cameras, targets)):
        kind = source_kind(target)
        if kind == "file" and not Path(target).is_file():
            raise SourceError(f"camera {name}: {target} is neither a stream URL ({', '.join(NETWORK_SCHEMES)}), a V4L2 "
                              "device (/dev/videoN) nor a video file")
        sources.append(Source(i, name, kind, target))
    return sources


def _name_of(arg: str, cameras: Sequence[str]) -> str | None:
    """The camera ``arg`` names as ``NAME=...`` (a URL's own '=' is not taken for one), else None."""
    name, sep, _ = arg.partition("=")
    return name if sep and name in cameras else None


def parse_offsets(args: Sequence[str], cameras: Sequence[str]) -> list[float]:
    """Per-camera offsets in seconds (rig order) from ``NAME=MS`` items (milliseconds added to that camera's capture
    times); SourceError for an unknown camera or a value that is not a number."""
    offsets = [0.0] * len(cameras)
    for arg in args:
        name, sep, value = arg.partition("=")
        if not sep or name not in cameras:
            raise SourceError(f"--offset {arg}: expected NAME=MILLISECONDS with NAME one of {', '.join(cameras)}")
        try:
            offsets[list(cameras).index(name)] = float(value) / 1e3
        except ValueError:
            raise SourceError(f"--offset {arg}: {value!r} is not a number of milliseconds") from None
    return offsets
