"""What the media says about the flight besides its pixels: the camera (for a focal length to start
self-calibration from) and where each frame was taken.

- Stills (a zip or folder): every photo's EXIF (:mod:`workers.drone.exif`), read once.
- Video: DJI telemetry (:mod:`workers.drone.srt`) from an uploaded ``.SRT`` file, else from the video's
  own subtitle stream.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from workers.common.images import ImageInputError, read_image_size
from workers.common.jobctx import JobInputError

from .exif import GeoPoint, PhotoMeta, read_photo_meta
from .frames import open_media, still_files
from .selfcal import FocalPrior, default_focal_prior, focal_prior_from_exif, focal_prior_from_telemetry
from .srt import Telemetry, parse_srt, read_embedded


@dataclass
class FlightMeta:
    """``kind`` 'images' or 'video'; ``size`` (width, height) of the first frame as decoded (None when
    unknown); ``photos`` file name -> EXIF facts (stills); ``telemetry`` the video's positions over time
    and ``telemetry_source`` ('sidecar' or 'embedded'); ``notes`` what could not be read."""

    kind: str
    size: tuple[int, int] | None
    photos: dict[str, PhotoMeta] = field(default_factory=dict)
    telemetry: Telemetry | None = None
    telemetry_source: str | None = None
    notes: list[str] = field(default_factory=list)

    def focal_prior(self) -> FocalPrior:
        """Where self-calibration starts: the EXIF of the camera most of the photos come from, the
        telemetry's 35 mm equivalent, else a default field of view (:mod:`workers.drone.selfcal`)."""
        w, h = self.size if self.size is not None else (1920, 1080)
        if self.photos:
            models = Counter(m.model for m in self.photos.values())
            common = models.most_common(1)[0][0]
            for meta in self.photos.values():
                if meta.model == common:
                    prior = focal_prior_from_exif(meta, w, h)
                    if prior is not None:
                        return prior
        if self.telemetry is not None and self.telemetry.focal_35mm:
            return focal_prior_from_telemetry(self.telemetry.focal_35mm, w, h)
        return default_focal_prior(w)

    @property
    def gps_source(self) -> str | None:
        """'exif', 'srt sidecar', 'srt embedded' or None (no positions)."""
        if any(m.gps is not None for m in self.photos.values()):
            return "exif"
        if self.telemetry is not None:
            return f"srt {self.telemetry_source}"
        return None

    @property
    def altitude(self) -> str:
        """What the positions' altitudes are, in words."""
        if self.gps_source == "exif":
            return "EXIF GPSAltitude (metres, as the camera recorded it)"
        if self.telemetry is not None:
            return f"telemetry {self.telemetry.altitude or 'none'} (metres)"
        return "none"

    def positions_by_name(self) -> dict[str, GeoPoint]:
        """Stills: file name -> GPS position, for the photos that have one (a survey's plan: blocks, pairs)."""
        return {n: m.gps for n, m in self.photos.items() if m.gps is not None}


def read_flight_meta(media: str | Path, media_name: str | None = None, telemetry: bytes | None = None
                     ) -> FlightMeta:
    """The :class:`FlightMeta` of a media file (video, zip or folder of stills); ``telemetry`` the bytes
    of an uploaded DJI ``.SRT`` file (for a video). Raises JobInputError when that file holds no
    positions; unreadable EXIF is simply absent."""
    source = open_media(media, media_name)
    if source.kind == "images":
        photos: dict[str, PhotoMeta] = {}
        size = None
        for name, data in still_files(media, media_name):
            meta = read_photo_meta(data)
            photos[name] = meta
            if size is None:
                try:
                    s = read_image_size(data)
                except ImageInputError:
                    continue
                size = (s.width, s.height) if (meta.orientation or 1) < 5 else (s.height, s.width)
        out = FlightMeta("images", size, photos)
        if telemetry is not None:
            out.notes.append("a telemetry file was given with still images: the photos' EXIF GPS is used instead")
        return out
    out = FlightMeta("video", _video_size(media))
    if telemetry is not None:
        try:
            out.telemetry, out.telemetry_source = parse_srt(telemetry), "sidecar"
        except ValueError as exc:
            raise JobInputError(f"telemetry: {exc}") from None
    else:
        embedded = read_embedded(media)
        if embedded is not None:
            out.telemetry, out.telemetry_source = embedded, "embedded"
    return out


def _video_size(path: str | Path) -> tuple[int, int] | None:
    import av

    try:
        with av.open(str(path)) as c:
            s = c.streams.video[0]
            return (int(s.width), int(s.height)) if s.width and s.height else None
    except (av.error.FFmpegError, OSError, ValueError, IndexError):
        return None


def centre_of(size: tuple[int, int]) -> tuple[float, float]:
    """The principal point (cx, cy) of an image of ``size`` (width, height) at its centre (pixel-centre
    convention: (0, 0) is the first pixel's centre)."""
    return (size[0] - 1) / 2.0, (size[1] - 1) / 2.0


def check_prior(prior: FocalPrior, size: tuple[int, int]) -> None:
    """Raise JobInputError when a focal length from the media's metadata cannot be this camera's
    (a field of view outside 10..170 degrees)."""
    fov = 2 * math.degrees(math.atan(0.5 * size[0] / prior.focal_px))
    if not 10 <= fov <= 170:
        raise JobInputError(f"{prior.detail} gives a {fov:.0f} degree field of view for {size[0]} px wide images: "
                            "give the intrinsics (fx, fy, cx, cy) instead")
