"""The camera's make, model and focal length: from the rig file ([camera] make, model,
pixel_pitch_um) into each photo's EXIF (Make, Model, FocalLength) and the GCS's
CAMERA_INFORMATION."""

from __future__ import annotations

import shutil
import subprocess
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import piexif
import pytest

from insulator_rs.exceptions import ConfigError
from insulator_rs.geodesy import GeoPoint
from insulator_rs.mavlink.gcs import CameraDescription
from insulator_rs.report import ReportWriter
from insulator_rs.rig import RIGS_DIR, load_rig, simulator_rig


def test_the_simulator_rig_names_its_camera():
    rig = simulator_rig()
    assert (rig.lens.make, rig.lens.model, rig.lens.pixel_pitch_um) == ("insulator_rs", "simulated camera", 3.45)
    exif = rig.exif_camera()
    assert exif["focal_length_mm"] == pytest.approx(0.5 * (rig.camera.fx + rig.camera.fy) * 3.45e-3)


def _rig(tmp_path: Path, extra: str) -> Path:
    text = (RIGS_DIR / "simulator.toml").read_text()
    # the detection camera's lens only: the rig without its [inspection_camera] table
    text = text[:text.index("[inspection_camera]")] + text[text.index("[lidar]"):]
    text = text.replace('make = "insulator_rs"', "").replace('model = "simulated camera"', "")
    text = text.replace("pixel_pitch_um = 3.45", "").replace('calibration = "simulator_camera.yaml"',
                                                             'calibration = "simulator_camera.yaml"\n' + extra)
    shutil.copy(RIGS_DIR / "simulator_camera.yaml", tmp_path / "simulator_camera.yaml")
    p = tmp_path / "rig.toml"
    p.write_text(text)
    return p


def test_a_rig_without_them_gives_none(tmp_path):
    rig = load_rig(_rig(tmp_path, ""))
    assert rig.exif_camera() == {"make": None, "model": None, "focal_length_mm": None}


@pytest.mark.parametrize("extra, field", [('make = ""', "camera.make"), ("model = 3", "camera.model"),
                                          ('make = "' + "x" * 33 + '"', "camera.make"),
                                          ('model = "caf\\u00e9"', "camera.model"),
                                          ("pixel_pitch_um = 0", "camera.pixel_pitch_um"),
                                          ("pixel_pitch_um = true", "camera.pixel_pitch_um"),
                                          ("pixel_pitch_um = 1e9", "camera.pixel_pitch_um")])
def test_bad_names_and_pitches_are_refused(tmp_path, extra, field):
    with pytest.raises(ConfigError, match=f"rig.toml: {field}: expected"):
        load_rig(_rig(tmp_path, extra))


def test_the_photo_exif_names_the_camera(tmp_path):
    rig = simulator_rig()
    w = ReportWriter(tmp_path / "r", origin=GeoPoint(47.0, 8.0, 400.0))
    rec = w.save_photo("p.jpg", np.zeros((48, 64, 3), np.uint8), time_utc=datetime(2026, 6, 1, tzinfo=timezone.utc),
                       position_enu=np.array([1.0, 2.0, 3.0]), yaw_enu=0.0, **rig.exif_camera())
    w.close()
    path = tmp_path / "r" / rec["file"]
    ex = piexif.load(str(path))
    assert ex["0th"][piexif.ImageIFD.Make] == b"insulator_rs"
    assert ex["0th"][piexif.ImageIFD.Model] == b"simulated camera"
    num, den = ex["Exif"][piexif.ExifIFD.FocalLength]
    assert num / den == pytest.approx(rig.exif_camera()["focal_length_mm"], abs=0.01)
    assert piexif.GPSIFD.GPSLatitude in ex["GPS"]  # today's EXIF kept
    if shutil.which("exiftool"):  # an independent reader
        out = subprocess.run(["exiftool", "-s", "-Make", "-Model", "-FocalLength", str(path)],
                             capture_output=True, text=True, check=True).stdout
        assert "insulator_rs" in out and "simulated camera" in out and "mm" in out


def test_camera_information_from_the_rig():
    rig = simulator_rig()
    d = CameraDescription.from_camera_model(rig.camera, pixel_pitch_um=rig.lens.pixel_pitch_um,
                                            vendor=rig.lens.make, model=rig.lens.model)
    assert d.vendor == "insulator_rs" and d.model == "simulated camera"
    assert d.focal_length_mm == pytest.approx(rig.exif_camera()["focal_length_mm"])
    assert d.sensor_width_mm == pytest.approx(rig.camera.width * 3.45e-3)
