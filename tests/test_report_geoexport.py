"""The report in WGS-84: summary/CSV positions, GeoJSON (RFC 7946) and KML map layers.

References: pymap3d's ``geodetic2enu`` called here (not the package's geodesy module) takes
every written coordinate back to W, where it must land within 1 cm of the ENU it came from
(``ROUND_TRIP_M``); the ``geojson`` package validates the document, and the RFC 7946 rules it
does not check (position order lon,lat; no ``crs``; LineString of >= 2 positions; lat/lon
ranges) are checked here. The tower stands at 49.5 N 15.0 E: a lat/lon swap lands 600 km off.
"""

from __future__ import annotations

import csv
import json
import xml.etree.ElementTree as ET
from datetime import datetime, timezone

import geojson
import numpy as np
import pymap3d
import pytest

from insulator_rs.geodesy import GeoPoint
from insulator_rs.report import FlightClock, ReportWriter
from insulator_rs.report.geoexport import PATH_SPACING
from helpers.summaries import run_summary

ORIGIN = GeoPoint(49.5, 15.0, 420.0)
ROUND_TRIP_M = 0.01
KML_NS = {"k": "http://www.opengis.net/kml/2.2"}


def _to_enu(lat, lon, alt) -> np.ndarray:
    return np.array(pymap3d.geodetic2enu(lat, lon, alt, ORIGIN.lat, ORIGIN.lon, ORIGIN.alt))


def _flight(tmp_path, *, poses: int = 400):
    """A report with two insulators, three photos and a flown circle round the tower."""
    w = ReportWriter(tmp_path / "report", origin=ORIGIN)
    ang = np.linspace(0, 2 * np.pi, poses)
    path = np.stack([9 * np.cos(ang), 9 * np.sin(ang), 5 + 6 * ang / (2 * np.pi)], axis=1)
    for k, p in enumerate(path):
        w.log_pose(0.05 * k, p, ang[k] + np.pi, "explore")
    for _ in range(50):  # hovering: many equal samples
        w.log_pose(20.0, path[-1], 0.0, "inspect")
    clock = FlightClock(0.0, datetime(2026, 6, 1, 10, 0, tzinfo=timezone.utc))
    insulators = [{"id": 1, "center": np.array([2.43, -1.81, 9.08]), "axis": np.array([0.0, 0.0, 1.0]),
                   "observations": 10, "side": 1, "inspected": True, "photos": []},
                  {"id": 2, "center": np.array([-2.41, 1.82, 17.5]), "axis": np.array([0.0, 0.1, 0.99]),
                   "observations": 4, "side": -1, "inspected": False, "photos": []}]
    photos = []
    for k, (ins, pos, yaw) in enumerate(((1, path[40], 0.3), (1, path[60], 0.5), (2, path[300], -2.0))):
        rec = w.save_photo(f"insulator_{ins:02d}_{k + 1}.jpg", np.zeros((32, 32, 3), np.uint8),
                           time_utc=clock.at(2.0 * k), position_enu=pos, yaw_enu=yaw)
        photos.append({**rec, "insulator_id": ins, "position": pos, "yaw": yaw})
        insulators[ins - 1]["photos"].append(rec["file"])
    w.write_summary(run_summary("finished", insulators=insulators, photos=photos))
    w.close()
    return tmp_path / "report", insulators, photos, np.vstack([path, path[-1:]])


def _positions(geometry):
    c = geometry["coordinates"]
    return [c] if geometry["type"] == "Point" else c


def test_geojson_validates_and_round_trips_to_enu(tmp_path):
    out, insulators, photos, path = _flight(tmp_path)
    text = (out / "inspection.geojson").read_text()
    obj = geojson.loads(text)
    assert obj.is_valid, obj.errors()
    doc = json.loads(text)
    assert doc["type"] == "FeatureCollection" and "crs" not in doc
    for f in doc["features"]:
        assert f["type"] == "Feature" and isinstance(f["properties"], dict)
        for pos in _positions(f["geometry"]):
            assert len(pos) == 3 and all(isinstance(v, float) for v in pos)
            assert -180 <= pos[0] <= 180 and -90 <= pos[1] <= 90
    by_kind = {}
    for f in doc["features"]:
        by_kind.setdefault(f["properties"]["kind"], []).append(f)
    assert {k: len(v) for k, v in by_kind.items()} == {"tower_base": 1, "insulator": 2, "photo": 3,
                                                       "flight_path": 1}
    lon, lat, alt = by_kind["tower_base"][0]["geometry"]["coordinates"]
    assert np.linalg.norm(_to_enu(lat, lon, alt)) < ROUND_TRIP_M
    for f, ins in zip(by_kind["insulator"], insulators):
        lon, lat, alt = f["geometry"]["coordinates"]
        assert np.linalg.norm(_to_enu(lat, lon, alt) - ins["center"]) < ROUND_TRIP_M
        assert f["properties"]["id"] == ins["id"] and f["properties"]["photos"] == ins["photos"]
        assert "error_m" not in f["properties"]  # ground truth stays out of the crew's map
    for f, ph in zip(by_kind["photo"], photos):
        lon, lat, alt = f["geometry"]["coordinates"]
        assert np.linalg.norm(_to_enu(lat, lon, alt) - ph["position"]) < ROUND_TRIP_M
        assert f["properties"]["file"] == ph["file"] and f["properties"]["time_utc"] == ph["time_utc"]
        assert f["properties"]["heading_deg"] == pytest.approx(ph["heading_deg"])
    line = by_kind["flight_path"][0]["geometry"]
    assert line["type"] == "LineString" and len(line["coordinates"]) >= 2
    enu = np.array([_to_enu(lat, lon, alt) for lon, lat, alt in line["coordinates"]])
    # every vertex is a flown sample, the ends are the path's ends, and the thinning keeps the shape
    d = np.linalg.norm(enu[:, None, :] - path[None, :, :], axis=2).min(axis=1)
    assert d.max() < ROUND_TRIP_M
    assert np.linalg.norm(enu[0] - path[0]) < ROUND_TRIP_M and np.linalg.norm(enu[-1] - path[-1]) < ROUND_TRIP_M
    steps = np.linalg.norm(np.diff(enu, axis=0), axis=1)
    assert steps[:-1].min() >= PATH_SPACING - ROUND_TRIP_M and steps.max() < 1.0
    assert len(enu) < len(path)  # the hover's 50 equal samples are one vertex


def test_kml_holds_the_same_points(tmp_path):
    out, insulators, photos, path = _flight(tmp_path)
    root = ET.parse(out / "inspection.kml").getroot()
    marks = {}
    for pm in root.iter(f"{{{KML_NS['k']}}}Placemark"):
        name = pm.find("k:name", KML_NS).text
        coords = pm.find(".//k:coordinates", KML_NS).text.split()
        mode = pm.find(".//k:altitudeMode", KML_NS).text
        marks[name] = ([tuple(float(v) for v in c.split(",")) for c in coords], mode)
    for ins in insulators:
        (c,), mode = marks[f"insulator {ins['id']}"]
        assert mode == "absolute"
        assert np.linalg.norm(_to_enu(c[1], c[0], c[2]) - ins["center"]) < ROUND_TRIP_M
    for ph in photos:
        (c,), _ = marks[ph["file"]]
        assert np.linalg.norm(_to_enu(c[1], c[0], c[2]) - ph["position"]) < ROUND_TRIP_M
    line, mode = marks["flown path"]
    assert mode == "absolute" and len(line) >= 2
    assert np.linalg.norm(_to_enu(line[-1][1], line[-1][0], line[-1][2]) - path[-1]) < ROUND_TRIP_M


def test_summary_and_csv_give_wgs84(tmp_path):
    out, insulators, _, _ = _flight(tmp_path)
    s = json.loads((out / "summary.json").read_text())
    assert s["origin"]["lat"] == ORIGIN.lat and s["origin"]["lon"] == ORIGIN.lon
    for r, ins in zip(s["insulators"], insulators):
        g = r["wgs84"]
        assert np.linalg.norm(_to_enu(g["lat"], g["lon"], g["alt"]) - ins["center"]) < ROUND_TRIP_M
    for p in s["photos"]:
        g = p["wgs84"]
        assert np.linalg.norm(_to_enu(g["lat"], g["lon"], g["alt"]) - np.array(p["position"])) < ROUND_TRIP_M
    rows = list(csv.DictReader((out / "insulators.csv").open()))
    assert "error_m" not in rows[0] and "gt_instance_id" not in rows[0]  # ground truth is score.json's alone
    for r, ins in zip(rows, insulators):
        enu = _to_enu(float(r["lat_deg"]), float(r["lon_deg"]), float(r["alt_m"]))
        assert np.linalg.norm(enu - ins["center"]) < ROUND_TRIP_M
        assert np.linalg.norm(np.array([float(r["x_m"]), float(r["y_m"]), float(r["z_m"])]) - ins["center"]) < 1e-3


def test_a_report_without_a_path_or_finds_is_still_valid(tmp_path):
    w = ReportWriter(tmp_path / "r", origin=ORIGIN)
    w.log_pose(0.0, np.zeros(3), 0.0, "idle")
    w.write_summary(run_summary("aborted: no offboard"))
    w.close()
    header = (tmp_path / "r" / "insulators.csv").read_text().splitlines()[0]
    assert header.endswith(",photos")  # no ground-truth columns a flight cannot fill
    doc = geojson.loads((tmp_path / "r" / "inspection.geojson").read_text())
    assert doc.is_valid, doc.errors()
    assert [f["properties"]["kind"] for f in doc["features"]] == ["tower_base"]  # one pose: no LineString
    ET.parse(tmp_path / "r" / "inspection.kml")
