"""Inspection photos: JPEG with EXIF GPS position, altitude, heading and time.

References: the photos are read back with Pillow (and exiftool where installed), never
with piexif that wrote them; the expected WGS-84 position is pymap3d's ``enu2geodetic``
of the ENU position at the mission's tower base, called here directly. Tolerances follow
the EXIF rationals written: latitude/longitude 1e-8 deg (about 1 mm; the rationals hold
1e-6 arc-second), altitude 1 mm (stored in mm), heading 0.006 deg (stored in 0.01 deg),
time 1 ms.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pymap3d
import pytest
from hypothesis import given
from hypothesis import strategies as st
from PIL import Image

from insulator_rs.geodesy import GeoPoint
from insulator_rs.report import FlightClock, ReportWriter, compass_heading_deg
from insulator_rs.report.exif import photo_exif

GPS_IFD = 0x8825
EXIF_IFD = 0x8769
DEG_TOL = 1e-8
ALT_TOL = 1e-3
HEADING_TOL = 0.006

# (origin, ENU position of the vehicle, yaw in W): both hemispheres, below sea level, the antimeridian side.
CASES = [
    (GeoPoint(49.5, 15.0, 420.0), (2.4, -7.9, 11.3), 1.2),
    (GeoPoint(-33.45, -70.66, 550.0), (-6.0, 3.5, 8.0), -2.9),
    (GeoPoint(31.5, 35.5, -415.0), (5.0, 5.0, 3.0), math.pi / 2),  # Dead Sea shore: below the datum
    (GeoPoint(0.00001, -179.99999, 5.0), (-4.0, -3.0, 20.0), 0.0),  # a position across the equator and 180 deg
]


def _image() -> np.ndarray:
    """A BGR test image: the left half pure red in BGR order (channel 2), the right half grey."""
    img = np.full((96, 128, 3), 90, np.uint8)
    img[:, :64] = (0, 0, 255)
    return img


def _dms(values, ref) -> float:
    d, m, s = (float(v) for v in values)
    sign = -1.0 if ref in ("S", "W") else 1.0
    return sign * (d + m / 60 + s / 3600)


def _read_pil(path: Path) -> dict:
    im = Image.open(path)
    assert im.format == "JPEG"
    exif = im.getexif()
    gps = exif.get_ifd(GPS_IFD)
    ex = exif.get_ifd(EXIF_IFD)
    alt = float(gps[6]) * (-1.0 if gps[5] in (1, b"\x01") else 1.0)
    h, m, s = (float(v) for v in gps[7])
    gps_time = datetime.strptime(gps[29], "%Y:%m:%d").replace(tzinfo=timezone.utc) + timedelta(
        hours=h, minutes=m, seconds=s)
    original = datetime.strptime(ex[0x9003], "%Y:%m:%d %H:%M:%S").replace(tzinfo=timezone.utc) + timedelta(
        milliseconds=int(ex[0x9291]))
    return {"lat": _dms(gps[2], gps[1]), "lon": _dms(gps[4], gps[3]), "alt": alt, "heading": float(gps[17]),
            "heading_ref": gps[16], "datum": gps[18], "gps_time": gps_time, "original": original,
            "offset": ex[0x9011], "rgb": np.asarray(im.convert("RGB"))}


def _photos(tmp_path: Path):
    t0 = datetime(2026, 6, 1, 23, 59, 59, 999_000, tzinfo=timezone.utc)  # the next ms is another day
    for k, (origin, enu, yaw) in enumerate(CASES):
        w = ReportWriter(tmp_path / f"r{k}", origin=origin)
        t = FlightClock(100.0, t0).at(100.0 + 0.25 * k)
        rec = w.save_photo(f"insulator_01_{k + 1}.jpg", _image(), time_utc=t, position_enu=np.array(enu),
                           yaw_enu=yaw, gimbal_pitch=math.radians(-10.0))
        w.close()
        yield tmp_path / f"r{k}" / rec["file"], origin, enu, yaw, t, rec


def test_photo_gps_heading_and_time_read_back_with_pil(tmp_path):
    for path, origin, enu, yaw, t, rec in _photos(tmp_path):
        got = _read_pil(path)
        lat, lon, alt = pymap3d.enu2geodetic(*enu, origin.lat, origin.lon, origin.alt)
        assert abs(got["lat"] - lat) < DEG_TOL and abs(got["lon"] - lon) < DEG_TOL, (path, got, lat, lon)
        assert abs(got["alt"] - alt) < ALT_TOL
        expected_heading = (90.0 - math.degrees(yaw)) % 360.0
        assert abs(got["heading"] - expected_heading) < HEADING_TOL and got["heading_ref"] == "T"
        assert got["datum"] == "WGS-84" and got["offset"] == "+00:00"
        assert abs((got["gps_time"] - t).total_seconds()) < 1e-3
        assert abs((got["original"] - t).total_seconds()) < 1e-3
        # the report's own record says the same
        assert rec["wgs84"]["lat"] == pytest.approx(lat, abs=1e-9) and rec["heading_deg"] == pytest.approx(
            expected_heading, abs=1e-9)
        # the pixels: BGR in, the red half red when a viewer decodes it
        rgb = got["rgb"].astype(int)
        assert rgb[:, :60, 0].mean() > 240 and rgb[:, :60, 2].mean() < 15
        assert abs(rgb[:, 70:].mean() - 90) < 3


@pytest.mark.skipif(shutil.which("exiftool") is None,
                    reason="exiftool not installed (apt-get install libimage-exiftool-perl)")
def test_photo_gps_read_back_with_exiftool(tmp_path):
    for path, origin, enu, yaw, t, _ in _photos(tmp_path):
        out = subprocess.run(["exiftool", "-j", "-n", "-Composite:GPSLatitude", "-Composite:GPSLongitude",
                              "-Composite:GPSAltitude", "-GPSImgDirection", "-GPSImgDirectionRef",
                              "-Composite:GPSDateTime", "-DateTimeOriginal", "-SubSecTimeOriginal", str(path)],
                             capture_output=True, text=True, check=True, timeout=60)
        doc = json.loads(out.stdout)[0]
        lat, lon, alt = pymap3d.enu2geodetic(*enu, origin.lat, origin.lon, origin.alt)
        assert abs(doc["GPSLatitude"] - lat) < DEG_TOL and abs(doc["GPSLongitude"] - lon) < DEG_TOL
        assert abs(doc["GPSAltitude"] - alt) < ALT_TOL
        assert abs(doc["GPSImgDirection"] - (90.0 - math.degrees(yaw)) % 360.0) < HEADING_TOL
        assert doc["GPSImgDirectionRef"] == "T"
        assert doc["GPSDateTime"] == t.strftime("%Y:%m:%d %H:%M:%S.") + f"{t.microsecond // 1000:03d}Z"
        assert doc["DateTimeOriginal"] == t.strftime("%Y:%m:%d %H:%M:%S")


def test_heading_from_yaw_known_directions():
    """Yaw in W is counter-clockwise from east; the compass heading is clockwise from north."""
    for yaw_deg, heading in ((0, 90), (90, 0), (180, 270), (-90, 180), (135, 315), (-45, 135), (450, 0),
                             (-270, 0), (1e-15, 90)):
        assert compass_heading_deg(math.radians(yaw_deg)) == pytest.approx(heading, abs=1e-9)
    assert 0.0 <= compass_heading_deg(math.pi / 2 + 1e-13) < 360.0
    assert compass_heading_deg(-1e-300) < 360.0


@given(st.floats(-20.0, 20.0, allow_nan=False))
def test_heading_matches_the_bearing_of_the_body_x_axis(yaw):
    """Independent reference: the bearing (clockwise from north) of the body x axis (cos yaw, sin yaw) in ENU."""
    east, north = math.cos(yaw), math.sin(yaw)
    bearing = math.degrees(math.atan2(east, north)) % 360.0
    h = compass_heading_deg(yaw)
    assert 0.0 <= h < 360.0
    assert min(abs(h - bearing), 360.0 - abs(h - bearing)) < 1e-9


def test_bad_photo_input_is_named(tmp_path):
    w = ReportWriter(tmp_path / "r", origin=GeoPoint(49.5, 15.0, 420.0))
    t = datetime(2026, 6, 1, tzinfo=timezone.utc)
    with pytest.raises(ValueError, match="yaw_enu"):
        w.save_photo("a.jpg", _image(), time_utc=t, position_enu=np.zeros(3), yaw_enu=float("nan"))
    with pytest.raises(ValueError, match="position_enu"):
        w.save_photo("a.jpg", _image(), time_utc=t, position_enu=np.array([0, np.inf, 0]), yaw_enu=0.0)
    with pytest.raises(ValueError, match="time_utc"):
        w.save_photo("a.jpg", _image(), time_utc=datetime(2026, 6, 1), position_enu=np.zeros(3), yaw_enu=0.0)
    with pytest.raises(ValueError, match="image_bgr"):
        w.save_photo("a.jpg", np.zeros((4, 4), np.uint8), time_utc=t, position_enu=np.zeros(3), yaw_enu=0.0)
    with pytest.raises(ValueError, match="name"):
        w.save_photo("../a.jpg", _image(), time_utc=t, position_enu=np.zeros(3), yaw_enu=0.0)
    with pytest.raises(ValueError, match="name"):
        w.save_photo("a.png", _image(), time_utc=t, position_enu=np.zeros(3), yaw_enu=0.0)
    with pytest.raises(ValueError, match="geo"):
        photo_exif(geo=GeoPoint(95.0, 0.0, 0.0), heading_deg=0.0, time_utc=t)
    w.close()
    assert not list((tmp_path / "r" / "images").iterdir())


def test_flight_clock_maps_vehicle_time_to_utc():
    t0 = datetime(2026, 3, 29, 0, 59, 59, tzinfo=timezone(timedelta(hours=1)))
    c = FlightClock(12.5, t0)
    assert c.at(12.5) == t0 and c.at(12.5).tzinfo == timezone.utc
    assert c.at(14.0) - t0 == timedelta(seconds=1.5)
    with pytest.raises(ValueError, match="utc"):
        FlightClock(0.0, datetime(2026, 1, 1))
    with pytest.raises(ValueError, match="vehicle_time"):
        c.at(float("nan"))
