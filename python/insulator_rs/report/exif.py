"""Inspection photos as JPEG files whose EXIF says where, which way and when they were taken.

Tags written (EXIF 2.32 / CIPA DC-008, with piexif):

* GPS IFD: ``GPSVersionID`` 2.3.0.0, ``GPSLatitude``/``GPSLongitude`` (degrees, minutes,
  seconds to 1e-6 arc-second, about 0.03 mm) with their N/S and E/W refs,
  ``GPSAltitude`` (mm) with ``GPSAltitudeRef`` 0 above / 1 below the datum,
  ``GPSImgDirection`` (0.01 deg) with ``GPSImgDirectionRef`` "T" (true north: W is ENU, so
  its y axis is true north), ``GPSTimeStamp``/``GPSDateStamp`` (UTC, ms), ``GPSMapDatum`` WGS-84.
* Exif IFD: ``DateTimeOriginal`` (UTC) with ``SubSecTimeOriginal`` (ms) and
  ``OffsetTimeOriginal`` "+00:00", so readers need not guess the time zone.
* 0th IFD: ``ImageDescription`` (which insulator, gimbal pitch), ``Software``, ``DateTime``.

The altitude is the mission tower's ``alt`` plus the height in W: it is in the tower
altitude's own vertical datum (pymap3d takes it as WGS-84 ellipsoidal height; a mission
that gives the tower's height above mean sea level gets heights above mean sea level).
"""

from __future__ import annotations

import io
import math
from typing import Any
from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np
import piexif

from insulator_rs.geodesy import GeoPoint
from insulator_rs.report.folder import write_atomic

JPEG_QUALITY = 95  # keeps the insulator's surface detail (cracks, flashover marks) for the crew
SOFTWARE = "insulator_rs"
# Denominators of the EXIF rationals: latitude/longitude seconds to 1e-6", altitude to 1 mm,
# image direction to 0.01 deg, time stamp seconds to 1 ms.
_ARCSEC_DEN = 1_000_000
_ALT_DEN = 1000
_DIR_DEN = 100
_SEC_DEN = 1000


def compass_heading_deg(yaw_enu: float) -> float:
    """The compass heading (deg clockwise from true north, in [0, 360)) of a yaw in W
    (rad, counter-clockwise from east, ENU): heading = 90 deg - yaw."""
    if not math.isfinite(yaw_enu):
        raise ValueError(f"yaw_enu: must be finite, got {yaw_enu}")
    h = (90.0 - math.degrees(yaw_enu)) % 360.0
    return 0.0 if h >= 360.0 else h  # -1e-17 % 360 rounds to 360.0


def _dms(value_deg: float) -> tuple[tuple[int, int], tuple[int, int], tuple[int, int]]:
    """|value| as EXIF (degrees, minutes, seconds) rationals; integer arithmetic so a
    rounded-up 60" carries into the minutes."""
    total = round(abs(value_deg) * 3600 * _ARCSEC_DEN)
    deg, rest = divmod(total, 3600 * _ARCSEC_DEN)
    minutes, sec = divmod(rest, 60 * _ARCSEC_DEN)
    return (int(deg), 1), (int(minutes), 1), (int(sec), _ARCSEC_DEN)


def _utc(time_utc: datetime) -> datetime:
    if not isinstance(time_utc, datetime) or time_utc.tzinfo is None:
        raise ValueError(f"time_utc: must be a timezone-aware datetime, got {time_utc!r}")
    return time_utc.astimezone(timezone.utc)


def photo_exif(*, geo: GeoPoint, heading_deg: float, time_utc: datetime, description: str = "",
               make: str | None = None, model: str | None = None, focal_length_mm: float | None = None) -> bytes:
    """The EXIF block (bytes for :func:`write_jpeg`) of a photo taken at ``geo`` (WGS-84),
    looking along ``heading_deg`` (deg clockwise from true north), at ``time_utc``; with the
    camera's ``make``, ``model`` (Make, Model) and ``focal_length_mm`` (FocalLength) where known."""
    for name, v in (("geo.lat", geo.lat), ("geo.lon", geo.lon), ("geo.alt", geo.alt), ("heading_deg", heading_deg)):
        if not math.isfinite(v):
            raise ValueError(f"{name}: must be finite, got {v}")
    if not (-90.0 <= geo.lat <= 90.0 and -180.0 <= geo.lon <= 180.0):
        raise ValueError(f"geo: latitude/longitude out of range: {geo.lat}, {geo.lon}")
    t = _utc(time_utc)
    ms = t.microsecond // 1000
    stamp = t.strftime("%Y:%m:%d %H:%M:%S")
    direction = round((heading_deg % 360.0) * _DIR_DEN) % (360 * _DIR_DEN)
    gps = {
        piexif.GPSIFD.GPSVersionID: (2, 3, 0, 0),
        piexif.GPSIFD.GPSLatitudeRef: b"N" if geo.lat >= 0 else b"S",
        piexif.GPSIFD.GPSLatitude: _dms(geo.lat),
        piexif.GPSIFD.GPSLongitudeRef: b"E" if geo.lon >= 0 else b"W",
        piexif.GPSIFD.GPSLongitude: _dms(geo.lon),
        piexif.GPSIFD.GPSAltitudeRef: 0 if geo.alt >= 0 else 1,
        piexif.GPSIFD.GPSAltitude: (round(abs(geo.alt) * _ALT_DEN), _ALT_DEN),
        piexif.GPSIFD.GPSImgDirectionRef: b"T",
        piexif.GPSIFD.GPSImgDirection: (direction, _DIR_DEN),
        piexif.GPSIFD.GPSTimeStamp: ((t.hour, 1), (t.minute, 1), (t.second * _SEC_DEN + ms, _SEC_DEN)),
        piexif.GPSIFD.GPSDateStamp: t.strftime("%Y:%m:%d").encode(),
        piexif.GPSIFD.GPSMapDatum: b"WGS-84",
    }
    exif: dict[int, Any] = {
        piexif.ExifIFD.DateTimeOriginal: stamp.encode(),
        piexif.ExifIFD.SubSecTimeOriginal: f"{ms:03d}".encode(),
        piexif.ExifIFD.OffsetTimeOriginal: b"+00:00",
    }
    zeroth = {piexif.ImageIFD.Software: SOFTWARE.encode(), piexif.ImageIFD.DateTime: stamp.encode()}
    if description:
        zeroth[piexif.ImageIFD.ImageDescription] = description.encode("ascii", "replace")
    if make:
        zeroth[piexif.ImageIFD.Make] = make.encode("ascii", "replace")
    if model:
        zeroth[piexif.ImageIFD.Model] = model.encode("ascii", "replace")
    if focal_length_mm is not None:
        if not (math.isfinite(focal_length_mm) and focal_length_mm > 0):
            raise ValueError(f"focal_length_mm: must be finite and > 0, got {focal_length_mm}")
        exif[piexif.ExifIFD.FocalLength] = (round(focal_length_mm * 100), 100)
    return bytes(piexif.dump({"0th": zeroth, "Exif": exif, "GPS": gps}))


def write_jpeg(path: Path, image_bgr: np.ndarray, *, exif: bytes, quality: int = JPEG_QUALITY) -> Path:
    """Encode ``image_bgr`` ((H, W, 3) uint8, OpenCV's channel order) as JPEG with ``exif``
    and write it atomically (temp file + rename: a kill never leaves half a photo)."""
    img = np.asarray(image_bgr)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8 or img.shape[0] == 0 or img.shape[1] == 0:
        raise ValueError(f"image_bgr: expected an (H, W, 3) uint8 image, got {img.dtype} {img.shape}")
    ok, encoded = cv2.imencode(".jpg", np.ascontiguousarray(img), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise OSError(f"{path}: could not encode the image as JPEG")
    out = io.BytesIO()
    piexif.insert(exif, encoded.tobytes(), out)
    return write_atomic(Path(path), out.getvalue(), durable=True)
