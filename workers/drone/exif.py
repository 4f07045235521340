"""What a still photo's EXIF says about its camera and where it was taken: the focal length (in mm,
35 mm equivalent, focal-plane resolution), the camera's make and model, and the GPS position.

Read with Pillow from the file's bytes (JPEG, TIFF, PNG eXIf, WebP), header only: the pixels are not
decoded. Tags that are absent or unreadable come back as None; a photo without EXIF is not an error.
"""
from __future__ import annotations

import io
import math
from dataclasses import dataclass

from PIL import Image, UnidentifiedImageError

_EXIF_IFD = 0x8769
_GPS_IFD = 0x8825
_MAKE, _MODEL, _ORIENTATION = 0x010F, 0x0110, 0x0112
_FOCAL_LENGTH = 0x920A
_FOCAL_35MM = 0xA405
_FOCAL_PLANE_X_RES = 0xA20E
_FOCAL_PLANE_UNIT = 0xA210
_PIXEL_X = 0xA002
_GPS_LAT_REF, _GPS_LAT, _GPS_LON_REF, _GPS_LON, _GPS_ALT_REF, _GPS_ALT = 1, 2, 3, 4, 5, 6
_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}  # EXIF ResolutionUnit: inch, cm, mm, um


@dataclass(frozen=True)
class GeoPoint:
    """WGS84 latitude and longitude (degrees, north and east positive) and altitude (metres, as the
    device wrote it: GPS EXIF altitude above sea level, DJI telemetry absolute or relative; None when
    absent)."""

    lat: float
    lon: float
    alt: float | None


@dataclass(frozen=True)
class PhotoMeta:
    """The EXIF facts a reconstruction uses (each None when the photo does not carry it).

    focal_mm: FocalLength; focal_35mm: FocalLengthIn35mmFilm; focal_plane_mm_per_px: the size of a
    pixel on the sensor in mm (from FocalPlaneXResolution and its unit) for an image ``exif_width``
    pixels wide (PixelXDimension, the width the camera wrote it at); gps: the position; orientation:
    the EXIF Orientation tag (5-8: the decoded image is turned by 90 degrees)."""

    make: str | None = None
    model: str | None = None
    focal_mm: float | None = None
    focal_35mm: float | None = None
    focal_plane_mm_per_px: float | None = None
    exif_width: int | None = None
    gps: GeoPoint | None = None
    orientation: int | None = None


def read_photo_meta(data: bytes) -> PhotoMeta:
    """The :class:`PhotoMeta` of an image file's bytes; an empty one when the file has no EXIF or is
    not an image Pillow can open."""
    try:
        with Image.open(io.BytesIO(data)) as im:
            exif = im.getexif()
            if not exif:
                return PhotoMeta()
            sub = exif.get_ifd(_EXIF_IFD)
            gps = exif.get_ifd(_GPS_IFD)
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError):
        return PhotoMeta()
    unit = _UNIT_MM.get(_int(sub.get(_FOCAL_PLANE_UNIT)) or 2)
    res = _positive(sub.get(_FOCAL_PLANE_X_RES))
    return PhotoMeta(
        make=_text(exif.get(_MAKE)), model=_text(exif.get(_MODEL)),
        focal_mm=_positive(sub.get(_FOCAL_LENGTH)), focal_35mm=_positive(sub.get(_FOCAL_35MM)),
        focal_plane_mm_per_px=unit / res if res and unit else None,
        exif_width=_int(sub.get(_PIXEL_X)), gps=_gps(gps), orientation=_int(exif.get(_ORIENTATION)))


def _gps(gps) -> GeoPoint | None:
    lat = _degrees(gps.get(_GPS_LAT), gps.get(_GPS_LAT_REF), "S")
    lon = _degrees(gps.get(_GPS_LON), gps.get(_GPS_LON_REF), "W")
    if lat is None or lon is None or not (-90 <= lat <= 90 and -180 <= lon <= 180) or (lat == 0 and lon == 0):
        return None
    alt = _float(gps.get(_GPS_ALT))
    if alt is not None and _int(gps.get(_GPS_ALT_REF)) == 1:
        alt = -alt  # GPSAltitudeRef 1: below sea level
    return GeoPoint(lat, lon, alt)


def _degrees(value, ref, negative: str) -> float | None:
    """EXIF (degrees, minutes, seconds) rationals and a N/S/E/W reference -> signed degrees."""
    try:
        d, m, s = (float(v) for v in value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    deg = d + m / 60.0 + s / 3600.0
    if not math.isfinite(deg):
        return None
    ref = ref.decode("ascii", "replace") if isinstance(ref, bytes) else str(ref or "")
    return -deg if ref.strip().upper().startswith(negative) else deg


def _float(value) -> float | None:
    try:
        v = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return v if math.isfinite(v) else None


def _positive(value) -> float | None:
    v = _float(value)
    return v if v is not None and v > 0 else None


def _int(value) -> int | None:
    v = _float(value)
    return int(v) if v is not None else None


def _text(value) -> str | None:
    if value is None:
        return None
    text = value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)
    text = text.strip("\x00 ").strip()
    return text or None
