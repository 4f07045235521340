"""Where a flight was: EXIF of stills (GPS, focal length), DJI .SRT telemetry (a file or the video's own
subtitle stream), WGS84 <-> UTM, and the robust similarity that puts a reconstruction there."""
from __future__ import annotations

import fractions
import io
import struct

import av
import cv2
import numpy as np
import piexif
import pytest

from workers.common.jobctx import JobInputError
from workers.drone.evaluation import Sim3
from workers.drone.exif import GeoPoint, read_photo_meta
from workers.drone.flightmeta import read_flight_meta
from workers.drone.geo import robust_similarity, to_geographic, to_projected, utm_epsg
from workers.drone.srt import parse_srt, read_embedded


def _jpeg(exif: dict) -> bytes:
    ok, jpg = cv2.imencode(".jpg", np.full((48, 64, 3), 128, np.uint8))
    out = io.BytesIO()
    piexif.insert(piexif.dump(exif), jpg.tobytes(), out)
    return out.getvalue()


def _dms(deg: float):
    d = int(deg)
    m = int((deg - d) * 60)
    s = (deg - d - m / 60) * 3600
    return (d, 1), (m, 1), (int(round(s * 10000)), 10000)


def test_exif_gps_focal_and_camera_are_read():
    data = _jpeg({
        "0th": {piexif.ImageIFD.Make: b"DJI", piexif.ImageIFD.Model: b"FC350"},
        "Exif": {piexif.ExifIFD.FocalLength: (361, 100), piexif.ExifIFD.FocalLengthIn35mmFilm: 20},
        "GPS": {piexif.GPSIFD.GPSLatitudeRef: b"S", piexif.GPSIFD.GPSLatitude: _dms(33.856784),
                piexif.GPSIFD.GPSLongitudeRef: b"W", piexif.GPSIFD.GPSLongitude: _dms(70.651234),
                piexif.GPSIFD.GPSAltitudeRef: 0, piexif.GPSIFD.GPSAltitude: (61275, 100)},
    })
    meta = read_photo_meta(data)
    assert (meta.make, meta.model, meta.focal_mm, meta.focal_35mm) == ("DJI", "FC350", 3.61, 20.0)
    assert meta.gps.lat == pytest.approx(-33.856784, abs=1e-7)
    assert meta.gps.lon == pytest.approx(-70.651234, abs=1e-7)
    assert meta.gps.alt == pytest.approx(612.75)


def test_photos_without_exif_or_gps_give_nothing():
    ok, png = cv2.imencode(".png", np.zeros((8, 8, 3), np.uint8))
    assert read_photo_meta(png.tobytes()).gps is None
    assert read_photo_meta(b"not an image").model is None
    no_fix = _jpeg({"GPS": {piexif.GPSIFD.GPSLatitudeRef: b"N", piexif.GPSIFD.GPSLatitude: ((0, 1), (0, 1), (0, 1)),
                            piexif.GPSIFD.GPSLongitudeRef: b"E", piexif.GPSIFD.GPSLongitude: ((0, 1), (0, 1), (0, 1))}})
    assert read_photo_meta(no_fix).gps is None  # 0, 0: a camera without a fix


# DJI's layouts, as the drones write them (made-up positions).
MAVIC3 = """1
00:00:00,000 --> 00:00:00,033
<font size="28">FrameCnt: 1, DiffTime: 33ms
2024-05-01 10:00:00.000
[iso: 100] [shutter: 1/640.0] [fnum: 2.8] [ev: 0] [color_md: default] [focal_len: 24.00] [latitude: 47.376800] [longitude: 8.541700] [rel_alt: 50.000 abs_alt: 480.500] [ct: 5500] </font>

2
00:00:00,033 --> 00:00:00,066
<font size="28">FrameCnt: 2, DiffTime: 33ms
2024-05-01 10:00:00.033
[iso: 100] [shutter: 1/640.0] [fnum: 2.8] [ev: 0] [color_md: default] [focal_len: 24.00] [latitude: 47.376900] [longitude: 8.541900] [rel_alt: 50.100 abs_alt: 480.600] [ct: 5500] </font>
"""

MAVIC2 = """1
00:00:00,000 --> 00:00:00,033
<font size="36">SrtCnt : 1, DiffTime : 33ms
2019-03-17 15:21:07,212,513
[iso : 100] [shutter : 1/500.0] [fnum : 280] [ev : 0] [ct : 5015] [color_md : default] [focal_len : 240] [latitude : 41.991700] [longtitude : -3.685600] [altitude: 987.438000] </font>

2
00:00:01,000 --> 00:00:01,033
<font size="36">SrtCnt : 2, DiffTime : 33ms
[iso : 100] [focal_len : 240] [latitude : 41.991800] [longtitude : -3.685400] [altitude: 988.438000] </font>
"""

PHANTOM4 = """1
00:00:00,000 --> 00:00:01,000
HOME(149.0251,-20.2532) 2017.08.05 14:11:51
GPS(149.0252,-20.2533,16) BAROMETER:1.9
ISO:100 Shutter:60 EV:0 Fnum:2.2

2
00:00:01,000 --> 00:00:02,000
HOME(149.0251,-20.2532) 2017.08.05 14:11:52
GPS(149.0254,-20.2535,16) BAROMETER:3.9
ISO:100 Shutter:60 EV:0 Fnum:2.2
"""

MAVIC_PRO = """1
00:00:00,000 --> 00:00:01,000
F/2.2, SS 320.15, ISO 100, EV 0, GPS (8.5372, 47.3745, 19), D 24.29m, H 19.60m, H.S 0.00m/s, V.S 0.00m/s
"""


def test_srt_layouts_give_positions_times_and_focal_length():
    t = parse_srt(MAVIC3)
    assert [s.start for s in t.samples] == pytest.approx([0.0, 0.033])
    assert (t.samples[0].position.lat, t.samples[0].position.lon) == (47.3768, 8.5417)
    assert t.altitude == "abs_alt" and t.samples[1].position.alt == 480.6
    assert t.focal_35mm == 24.0
    m2 = parse_srt(MAVIC2.encode())
    assert m2.samples[0].position.lon == -3.6856 and m2.altitude == "altitude" and m2.focal_35mm == 24.0
    p4 = parse_srt(PHANTOM4)
    # GPS(lon, lat, satellites): the third number is no altitude; the barometer's is.
    assert (p4.samples[1].position.lat, p4.samples[1].position.lon) == (-20.2535, 149.0254)
    assert p4.altitude == "barometer" and p4.samples[1].position.alt == 3.9
    pro = parse_srt(MAVIC_PRO)
    assert pro.samples[0].position == GeoPoint(47.3745, 8.5372, 19.6) and pro.altitude == "height"


def test_telemetry_is_interpolated_between_samples_and_absent_beyond():
    t = parse_srt(PHANTOM4)
    mid = t.position_at(0.5)
    assert mid.lat == pytest.approx(-20.2534) and mid.lon == pytest.approx(149.0253) and mid.alt == pytest.approx(2.9)
    assert t.position_at(1.8).lat == pytest.approx(-20.2535)  # after the last sample, within the gap allowed
    assert t.position_at(10.0) is None


def test_srt_without_positions_is_refused():
    with pytest.raises(ValueError, match="no GPS"):
        parse_srt("1\n00:00:00,000 --> 00:00:01,000\nhello\n")
    no_fix = MAVIC3.replace("47.376800", "0.000000").replace("8.541700", "0.000000")
    assert len(parse_srt(no_fix).samples) == 1  # the block before the fix is left out


_ASS = (b"[Script Info]\r\nScriptType: v4.00+\r\n\r\n[V4+ Styles]\r\nFormat: Name, Fontname, Fontsize\r\n"
        b"Style: Default,Arial,16\r\n\r\n[Events]\r\nFormat: Layer, Start, End, Style, Text\r\n")


def _video_with_subtitles(path, texts, fps=10):
    with av.open(str(path), "w") as out:
        video = out.add_stream("libx264", rate=fps)
        video.width, video.height, video.pix_fmt = 64, 48, "yuv420p"
        subs = out.add_stream("mov_text")
        subs.codec_context.subtitle_header = _ASS
        subs.time_base = fractions.Fraction(1, 1000)
        for i, text in enumerate(texts):
            for packet in video.encode(av.VideoFrame.from_ndarray(np.full((48, 64, 3), 10 * i, np.uint8), "bgr24")):
                out.mux(packet)
            body = text.encode()
            packet = av.Packet(struct.pack(">H", len(body)) + body)
            packet.stream, packet.pts, packet.dts, packet.duration = subs, i * 100, i * 100, 100
            packet.time_base = subs.time_base
            out.mux(packet)
        for packet in video.encode():
            out.mux(packet)


def test_telemetry_in_the_videos_own_subtitle_stream(tmp_path):
    path = tmp_path / "DJI_0001.MP4"
    _video_with_subtitles(path, [f"[latitude: 46.{i:04d}] [longitude: 7.5] [rel_alt: 30.0 abs_alt: {500 + i}.0]"
                                 for i in range(10)])
    t = read_embedded(path)
    assert len(t.samples) == 10 and t.altitude == "abs_alt"
    assert t.position_at(0.35).lat == pytest.approx(46.00035)
    meta = read_flight_meta(path)
    assert meta.kind == "video" and meta.telemetry_source == "embedded" and meta.gps_source == "srt embedded"
    plain = tmp_path / "plain.mp4"
    _video_with_subtitles(plain, ["no telemetry here"] * 3)
    assert read_embedded(plain) is None
    # A sidecar file wins over the stream; one without positions is the user's mistake.
    assert read_flight_meta(path, telemetry=PHANTOM4.encode()).telemetry_source == "sidecar"
    with pytest.raises(JobInputError, match="telemetry"):
        read_flight_meta(path, telemetry=b"1\n00:00:00,000 --> 00:00:01,000\nnothing\n")


def test_utm_zones_and_projection_round_trip():
    assert utm_epsg(47.3768, 8.5417) == 32632      # Zurich
    assert utm_epsg(-33.8688, 151.2093) == 32756   # Sydney
    assert utm_epsg(41.5486, -83.6986) == 32617    # the FC350 flight, Ohio
    assert utm_epsg(0.5, 179.9) == 32660
    pts = [GeoPoint(47.3768, 8.5417, 500.0), GeoPoint(47.3800, 8.5500, None)]
    xyz = to_projected(pts, 32632)
    # Zurich's UTM 32N coordinates (EPSG:32632), to the metre.
    assert xyz[0, :2] == pytest.approx([465_000, 5_247_000], abs=1_500)
    assert np.isnan(xyz[1, 2])
    back = to_geographic(np.nan_to_num(xyz), 32632)
    assert back[0].lat == pytest.approx(47.3768, abs=1e-9) and back[1].lon == pytest.approx(8.55, abs=1e-9)


def _rotation(axis, angle):
    return cv2.Rodrigues(np.asarray(axis, float) / np.linalg.norm(axis) * angle)[0]


def test_robust_similarity_finds_the_known_answer_despite_gps_glitches():
    rng = np.random.default_rng(0)
    src = rng.uniform(-1, 1, (40, 3)) * [3, 2, 0.1]  # a model of a survey: wide, flat
    truth = Sim3(25.0, _rotation([0.2, -0.4, 1.0], 2.1), np.array([120.0, -40.0, 300.0]))
    dst = truth.apply(src) + rng.normal(0, 0.5, (40, 3))
    bad = [3, 17, 29]
    dst[bad] += [[80, 0, 0], [0, -60, 20], [35, 35, -35]]
    fit = robust_similarity(src, dst)
    assert fit.sim.s == pytest.approx(25.0, rel=0.01)
    assert np.abs(fit.sim.R - truth.R).max() < 0.01
    assert not fit.inliers[bad].any() and fit.inliers.sum() == 37
    assert fit.rmse < 1.0


def test_a_single_flight_line_takes_its_roll_from_the_ground():
    rng = np.random.default_rng(1)
    # Model frame: cameras along x at height 1, ground z = 0 below them (up = +z in the model).
    src = np.column_stack([np.linspace(-2, 2, 12), np.zeros(12), np.ones(12)])
    truth = Sim3(30.0, _rotation([0.0, 0.0, 1.0], 0.7), np.array([10.0, 20.0, 100.0]))
    dst = truth.apply(src) + rng.normal(0, 0.05, (12, 3))
    fit = robust_similarity(src, dst, up=np.array([0.0, 0.0, 1.0]))
    assert fit.collinear
    np.testing.assert_allclose(fit.sim.R @ [0, 0, 1], [0, 0, 1], atol=1e-3)  # the ground stays level
    np.testing.assert_allclose(fit.sim.apply(np.array([[0.0, 0.5, 0.0]])), truth.apply(np.array([[0.0, 0.5, 0.0]])),
                               atol=0.2)
