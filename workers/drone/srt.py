"""DJI flight telemetry from subtitles: the ``.SRT`` file DJI drones write beside a video, or the same
text in the video's own subtitle stream (MP4 ``mov_text``, read with PyAV).

Each subtitle block covers a time span of the video and carries the drone's position in one of DJI's
text layouts (all seen in the wild; field names are matched case-insensitively):

- bracketed fields (Mavic 2/3, Air 2S, Mini): ``[latitude: 22.5312] [longitude: 113.9398]
  [rel_alt: 1.300 abs_alt: 135.213]`` (some firmwares write ``longtitude``, or ``[altitude: ...]``),
  and the 35 mm equivalent focal length ``[focal_len: 24.00]`` (``[focal_len : 240]``: tenths of mm);
- ``GPS(lon, lat, alt)`` with ``BAROMETER:81.5`` (Phantom 4, Inspire);
- ``GPS (lon, lat, satellites), D 24.3m, H 19.6m`` (Mavic Pro).

Altitude: the absolute one (``abs_alt``, ``altitude``) when the text has it, else the height above the
take-off point (``rel_alt``, barometer, ``H``); :attr:`Telemetry.altitude` says which.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .exif import GeoPoint

_TIME = re.compile(r"(\d+):(\d{2}):(\d{2})[,.](\d{1,3})\s*-->\s*(\d+):(\d{2}):(\d{2})[,.](\d{1,3})")
_NUMBER = r"([-+]?\d+(?:\.\d+)?)"
_FIELD = re.compile(r"\b(latitude|longitude|longtitude|rel_alt|abs_alt|altitude|focal_len)\s*:\s*" + _NUMBER, re.I)
_GPS = re.compile(r"\bGPS\s*\(\s*" + _NUMBER + r"\s*,\s*" + _NUMBER + r"(?:\s*,\s*" + _NUMBER + r")?\s*\)", re.I)
_BAROMETER = re.compile(r"\bBAROMETER\s*:\s*" + _NUMBER, re.I)
_HEIGHT = re.compile(r"(?:^|[\s,])H\s+" + _NUMBER + r"\s*m\b")
_TAG = re.compile(r"<[^>]*>")
# Altitude fields, most trusted first (an absolute altitude over one above the take-off point).
_ALTITUDE_ORDER = ("abs_alt", "altitude", "rel_alt", "barometer", "height", "gps")


@dataclass(frozen=True)
class TelemetrySample:
    """One subtitle block: its time span in the video (seconds) and the drone's position then."""

    start: float
    end: float
    position: GeoPoint


@dataclass(frozen=True)
class Telemetry:
    """A flight's positions over time, sorted by ``start``; ``altitude`` names the field the altitudes
    came from (see the module docstring; None when the text has none); ``focal_35mm`` the median 35 mm
    equivalent focal length the text gives (mm), or None."""

    samples: list[TelemetrySample]
    altitude: str | None
    focal_35mm: float | None

    def position_at(self, t: float, max_gap: float = 1.5) -> GeoPoint | None:
        """The position at video time ``t`` seconds: linear between the samples' start times around it,
        the first/last sample up to ``max_gap`` s beyond them; None outside or across a gap longer than
        ``max_gap`` (telemetry missing there)."""
        starts = np.array([s.start for s in self.samples])
        if len(starts) == 0 or t < starts[0] - max_gap or t > max(starts[-1], self.samples[-1].end) + max_gap:
            return None
        i = int(np.searchsorted(starts, t, side="right"))
        if i == 0:
            return self.samples[0].position
        if i == len(starts):
            return self.samples[-1].position
        a, b = self.samples[i - 1], self.samples[i]
        if b.start - a.start > max_gap:
            return None
        w = (t - a.start) / max(b.start - a.start, 1e-9)
        alt = None
        if a.position.alt is not None and b.position.alt is not None:
            alt = (1 - w) * a.position.alt + w * b.position.alt
        return GeoPoint((1 - w) * a.position.lat + w * b.position.lat,
                        (1 - w) * a.position.lon + w * b.position.lon, alt)


def parse_srt(text: str | bytes) -> Telemetry:
    """Telemetry from the text of a DJI ``.SRT`` file. Blocks without a usable position (no fix yet:
    0, 0) are left out. Raises ValueError when no block has one."""
    if isinstance(text, bytes):
        text = text.decode("utf-8-sig", errors="replace")
    blocks = re.split(r"\r?\n\s*\r?\n", text.replace("\r\n", "\n"))
    entries = []
    for block in blocks:
        m = _TIME.search(block)
        if not m:
            continue
        g = [int(v) for v in m.groups()]
        start = g[0] * 3600 + g[1] * 60 + g[2] + g[3] / 10 ** len(m.group(4))
        end = g[4] * 3600 + g[5] * 60 + g[6] + g[7] / 10 ** len(m.group(8))
        entries.append((start, end, block[m.end():]))
    return _telemetry(entries)


def _telemetry(entries: list[tuple[float, float, str]]) -> Telemetry:
    samples: list[tuple[float, float, float, float, dict[str, float]]] = []
    focal: list[float] = []
    for start, end, body in entries:
        fields = _fields(_TAG.sub(" ", body))
        if fields is None:
            continue
        lat, lon, alts, f35 = fields
        samples.append((start, end, lat, lon, alts))
        if f35 is not None:
            focal.append(f35)
    if not samples:
        raise ValueError("the subtitles hold no GPS position (DJI telemetry: latitude/longitude or GPS(...))")
    # One altitude field for the whole flight: the most trusted one that every sample has.
    kind = next((k for k in _ALTITUDE_ORDER if all(k in s[4] for s in samples)), None)
    out = [TelemetrySample(s, max(e, s), GeoPoint(lat, lon, alts.get(kind) if kind else None))
           for s, e, lat, lon, alts in sorted(samples, key=lambda x: x[0])]
    return Telemetry(out, kind, float(np.median(focal)) if focal else None)


def _fields(text: str) -> tuple[float, float, dict[str, float], float | None] | None:
    """(lat, lon, altitudes by field, 35 mm focal length) of one block's text, or None without a position."""
    values: dict[str, float] = {}
    focal = None
    for key, raw in _FIELD.findall(text):
        key = key.lower()
        if key == "focal_len":
            v = float(raw)
            focal = v / 10.0 if "." not in raw and v >= 100 else v  # '240' is tenths of a millimetre
        else:
            values["longitude" if key == "longtitude" else key] = float(raw)
    lat, lon = values.pop("latitude", None), values.pop("longitude", None)
    gps = _GPS.search(text)
    if (lat is None or lon is None) and gps:
        lon, lat = float(gps.group(1)), float(gps.group(2))
        if gps.group(3) is not None and "." in gps.group(3):
            values["gps"] = float(gps.group(3))  # an integer third value is the satellite count
    for name, pattern in (("barometer", _BAROMETER), ("height", _HEIGHT)):
        m = pattern.search(text)
        if m:
            values[name] = float(m.group(1))
    if lat is None or lon is None or (lat == 0 and lon == 0) or not (-90 <= lat <= 90 and -180 <= lon <= 180):
        return None
    return lat, lon, values, focal


def read_embedded(path: str | Path) -> Telemetry | None:
    """The telemetry in a video's subtitle streams (the first one that holds positions), or None when it
    has none or the file cannot be read as a video."""
    import av

    try:
        container = av.open(str(path))
    except (av.error.FFmpegError, OSError, ValueError):
        return None
    with container:
        for stream in container.streams.subtitles:
            entries = []
            try:
                for packet in container.demux(stream):
                    if packet.pts is None or packet.size <= 2:
                        continue
                    text = _packet_text(bytes(packet))
                    start = float(packet.pts * stream.time_base)
                    end = start + float((packet.duration or 0) * stream.time_base)
                    entries.append((start, end, text))
            except (av.error.FFmpegError, ValueError):
                pass
            try:
                return _telemetry(entries)
            except ValueError:
                container.seek(0)
                continue
    return None


def _packet_text(data: bytes) -> str:
    """A subtitle packet's text: MP4 ``mov_text`` (tx3g) starts with its length, big-endian; other
    formats (SubRip in MKV) are the text itself."""
    if len(data) >= 2:
        n = int.from_bytes(data[:2], "big")
        if n <= len(data) - 2:
            return data[2:2 + n].decode("utf-8", errors="replace")
    return data.decode("utf-8", errors="replace")
