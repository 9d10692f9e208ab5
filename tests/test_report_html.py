"""report.html: the page a line crew opens, rendered in a real headless Chromium.

The report is written by the flight's own ReportWriter (report.html comes with close()); the
browser is Debian's chromium driven over the DevTools pipe (tests/chromium_cdp.py). Checked in
the browser: every insulator is listed with its WGS-84 position and side, every thumbnail and
every full photo it links to loads (naturalWidth > 0), nothing is fetched from the network, the
map has a marker per insulator and per photo; a screenshot is taken.
"""

from __future__ import annotations

import base64
import json
import re
import os
import shutil
from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np
import pytest

from helpers.chromium_cdp import Chromium, find_chromium
from insulator_rs.app.cli import main
from insulator_rs.exceptions import ReportError
from insulator_rs.geodesy import GeoPoint
from insulator_rs.perception.photo_verdict import PhotoVerdict, Reason
from insulator_rs.report import FlightClock, ReportWriter
from insulator_rs.report.html import HTML_NAME, write_report_html
from insulator_rs.report.summary import FlightDetails, InsulatorRecord, PerceptionRecord, RunSummary

ORIGIN = GeoPoint(49.5, 15.0, 420.0)


def _photo(k: int) -> np.ndarray:
    img = np.zeros((480, 640, 3), np.uint8)
    img[:] = (200 - 20 * k, 170, 120 + 30 * k)
    cv2.rectangle(img, (280, 60), (360, 420), (40, 40, 40), -1)
    cv2.putText(img, f"photo {k + 1}", (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.0, (255, 255, 255), 2)
    return img


def _quality(gsd: float, fit: bool) -> dict:
    return {"gsd_mm_px": gsd, "frame_share": 0.05, "span_share": 0.7 if fit else 0.2, "whole_in_frame": True,
            "motion_blur_px": 0.1, "blur_within_limit": True}


def _check(verdict: PhotoVerdict) -> dict:
    """A photo's check record as the flight writes it (PhotoCheck.as_dict): the verdict and figures."""
    return {"verdict": verdict.to_json(), "fit": verdict.fit, "reasons": verdict.unfit_reasons,
            "span_share": 0.7 if verdict.fit else 0.2, "min_span": 0.6, "offset": [0.01, -0.02],
            "sharpness": 900.0, "error": None}


def make_report(tmp_path: Path) -> tuple[Path, list[dict], list[dict]]:
    """A finished report: three insulators (one with a fit photo, one with unfit photos, one
    skipped), a circle flown round the tower, three photos."""
    w = ReportWriter(tmp_path / "report", origin=ORIGIN)
    ang = np.linspace(0, 2 * np.pi, 300)
    path = np.stack([9 * np.cos(ang), 9 * np.sin(ang), 5 + 6 * ang / (2 * np.pi)], axis=1)
    for k, p in enumerate(path):
        w.log_pose(0.1 * k, p, ang[k] + np.pi, "explore")
    clock = FlightClock(0.0, datetime(2026, 6, 1, 10, 0, tzinfo=timezone.utc))
    insulators = [{"id": 1, "center": np.array([2.4, -1.8, 9.1]), "axis": np.array([0.0, 0.0, 1.0]),
                   "observations": 10, "side": 1, "confirmed": True, "inspected": True, "photos": []},
                  {"id": 2, "center": np.array([-2.4, 1.8, 9.0]), "axis": np.array([0.0, 0.1, 0.99]),
                   "observations": 6, "side": -1, "confirmed": True, "inspected": True, "photos": []},
                  {"id": 3, "center": np.array([-2.5, 1.9, 14.0]), "axis": np.array([0.0, 0.0, 1.0]),
                   "observations": 4, "side": -1, "confirmed": True, "inspected": False, "photos": []}]
    photos = []
    for k, (ins, pos, yaw, q, fit) in enumerate(((1, path[40], 0.3, _quality(1.8, True), True),
                                                 (2, path[160], -2.0, _quality(8.6, False), False),
                                                 (2, path[170], -2.2, _quality(8.7, False), False))):
        rec = w.save_photo(f"insulator_{ins:02d}_{k + 1}.jpg", _photo(k), time_utc=clock.at(2.0 * k),
                           position_enu=pos, yaw_enu=yaw, gimbal_pitch=-0.1)
        verdict = PhotoVerdict.passed() if fit else PhotoVerdict.unfit([Reason.TOO_SMALL])
        photos.append({**rec, "insulator_id": ins, "position": pos, "yaw": yaw, "quality": q,
                       "check": _check(verdict), "attempt": 1})
        insulators[ins - 1]["photos"].append(rec["file"])
    skipped = [{"insulator_id": 3, "position": [-6.0, 1.9, 14.0],
                "reason": "no safe route to the waypoint (enters the tower's safety volume)"}]
    w.write_summary(_run("finished", insulators, photos, skipped))
    w.close()
    return tmp_path / "report", insulators, photos


def _run(status: str, insulators: list[dict], photos: list[dict], skipped: list[dict]) -> RunSummary:
    """A flight's RunSummary, as the loop writes it."""
    return RunSummary(
        run="flight", status=status, detector="standin", method="bounded", flight_time_s=612.4,
        perception=PerceptionRecord(), insulators=[InsulatorRecord(**i) for i in insulators], photos=photos,
        flight=FlightDetails(mission="missions/test_tower.toml", rig="simulator", policy="immediate",
                             time_allocation="pmm", state="finish", vehicle="KinematicVehicle",
                             sensors="SimulatedSensors", failsafe=None, distance_m=240.0,
                             detections_dropped_by_sanitiser=None, inspections_skipped=skipped,
                             photo_camera=None, inspection_waypoints=[], transitions=[]))


def test_close_writes_a_self_contained_page(tmp_path):
    out, insulators, photos = make_report(tmp_path)
    text = (out / HTML_NAME).read_text(encoding="utf-8")
    for ins in insulators:
        assert f'id="insulator-{ins["id"]}"' in text
    for ph in photos:
        assert f'href="{ph["file"]}"' in text
    # self-contained: nothing to fetch (no external style, script, font or image)
    low = text.lower()
    assert "http://" not in low.replace('xmlns="http://www.w3.org/2000/svg"', "") and "https://" not in low
    assert "<script" not in low and "<link" not in low and "@import" not in low
    assert low.count("data:image/jpeg;base64,") == len(photos)
    assert "no safe route to the waypoint" in text  # skipped, with the reason
    assert "10 min 12.4 s" in text and "Insulator inspection — test_tower" in text  # flight time, mission
    # which insulators have no fit photo, and why
    assert "2 photos, none fit: too small (2x); the finest GSD 8.6 mm/px" in text
    assert ": ;" not in text and "none fit: ;" not in text  # never an empty reason
    assert "not inspected; skipped: no safe route" in text


@pytest.mark.skipif(find_chromium() is None, reason="Debian's chromium is not installed (.ci/run installs it)")
def test_report_renders_in_headless_chromium(tmp_path):
    out, insulators, photos = make_report(tmp_path)
    shot = tmp_path / "report.png"
    with Chromium() as browser:
        browser.open((out / HTML_NAME).resolve().as_uri())
        dom = browser.evaluate("""(async () => {
            const ids = [...document.querySelectorAll('section.insulator[data-insulator-id]')]
                .map(s => ({id: s.dataset.insulatorId, wgs84: s.querySelector('.wgs84').textContent,
                            side: s.querySelector('.side').textContent}));
            await Promise.all([...document.images].map(i => i.decode().catch(() => null)));
            const thumbs = [...document.images].map(i => ({src: i.currentSrc.slice(0, 30), w: i.naturalWidth,
                                                           ok: i.complete}));
            const links = [...document.querySelectorAll('a.full')].map(a => a.href);
            const full = await Promise.all(links.map(href => new Promise(res => {
                const im = new Image(); im.onload = () => res({href, w: im.naturalWidth, h: im.naturalHeight});
                im.onerror = () => res({href, w: 0, h: 0}); im.src = href; })));
            const res = performance.getEntriesByType('resource').map(r => r.name);
            return {ids, thumbs, full, res, markers: document.querySelectorAll('circle.insulator-marker').length,
                    photoMarkers: document.querySelectorAll('circle.photo-marker').length,
                    status: document.getElementById('status').textContent,
                    found: document.querySelector('#card-found .v').textContent};
        })()""")
        browser.screenshot(shot)
    assert [d["id"] for d in dom["ids"]] == [str(i["id"]) for i in insulators]
    for d in dom["ids"]:
        assert "° N" in d["wgs84"] and "side of the line" in d["side"]
    assert dom["ids"][0]["wgs84"].startswith("49.49")  # the tower at 49.5 N: lat first, not a swap
    assert len(dom["thumbs"]) == len(photos) and all(t["ok"] and t["w"] > 0 for t in dom["thumbs"])
    assert len(dom["full"]) == len(photos)
    assert all(f["w"] == 640 and f["h"] == 480 for f in dom["full"]), dom["full"]
    assert all(r.startswith(("file:", "data:")) for r in dom["res"]), dom["res"]  # nothing from a network
    assert dom["markers"] == 2 * len(insulators)  # top and side view
    assert dom["photoMarkers"] == 2 * len(photos)
    assert dom["status"] == "finished" and dom["found"] == "3"
    png = shot.read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert img.shape[1] == 1280 and img.shape[0] > 900  # the whole page, not one screen
    if os.environ.get("INSULATOR_RS_SCREENSHOT"):  # the docs' screenshot
        shutil.copy(shot, os.environ["INSULATOR_RS_SCREENSHOT"])


def test_missing_photo_is_shown_not_raised(tmp_path, capsys):
    out, _, photos = make_report(tmp_path)
    (out / photos[1]["file"]).unlink()
    (out / photos[2]["file"]).write_bytes(b"\xff\xd8 not a jpeg")
    assert main(["report", str(out)]) == 0
    err = capsys.readouterr().err
    assert f"warning: {photos[1]['file']}: file missing" in err
    assert f"warning: {photos[2]['file']}: not a decodable image" in err
    text = (out / HTML_NAME).read_text()
    assert 'id="problems"' in text and text.count("data:image/jpeg;base64,") == 1


@pytest.mark.parametrize("damage, message", [
    (lambda d: (d / "summary.json").unlink(), "summary.json: no summary.json in the report folder"),
    (lambda d: (d / "summary.json").write_text('{"status": "finished",\n "insulators": ['),
     "summary.json: not valid JSON (line 2"),
    (lambda d: (d / "summary.json").write_text("[1, 2]"), "summary.json: expected a JSON object"),
    (lambda d: (d / "summary.json").write_text('{"insulators": [{"id": 1}]}'),
     "summary.json: insulators[0] (id 1): wgs84 lat/lon/alt missing"),
    (lambda d: (d / "summary.json").write_bytes(b'{"a": "\xff"}'), "summary.json: not UTF-8 text (byte 7)"),
    (lambda d: (d / "inspection.geojson").unlink(), "inspection.geojson: no inspection.geojson"),
    (lambda d: (d / "inspection.geojson").write_text('{"type": "Feature"}'),
     "inspection.geojson: expected a GeoJSON FeatureCollection"),
    (lambda d: (d / "inspection.geojson").write_text(
        '{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {"kind": "photo"},'
        ' "geometry": {"type": "Point", "coordinates": [1, "x"]}}]}'),
     "inspection.geojson: features[0]"),
])
def test_bad_report_files_are_named_without_a_traceback(tmp_path, capsys, damage, message):
    out, _, _ = make_report(tmp_path)
    before = (out / HTML_NAME).read_text()
    damage(out)
    with pytest.raises(ReportError, match=re.escape(message.split(": ", 1)[1][:20])):
        write_report_html(out)
    assert main(["report", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("insulator-rs report: error: ") and message in err and "Traceback" not in err
    assert (out / HTML_NAME).read_text() == before  # the old page stays whole


def test_not_a_folder(tmp_path, capsys):
    assert main(["report", str(tmp_path / "nope")]) == 2
    assert "nope: no such report folder" in capsys.readouterr().err


def test_page_of_a_report_with_nothing_found(tmp_path):
    w = ReportWriter(tmp_path / "r", origin=ORIGIN)
    w.write_summary(_run("aborted: heartbeat lost", [], [], []))
    w.close()
    text = (tmp_path / "r" / HTML_NAME).read_text()
    assert "aborted: heartbeat lost" in text and 'class="status aborted"' in text
    assert json.loads((tmp_path / "r" / "summary.json").read_text())["status"].startswith("aborted")


def test_a_replay_says_it_carries_no_photos(tmp_path):
    """A replay re-runs perception on a recording and takes no photos: its page says so, and its
    insulators are found ones (grey), not red "no photo" ones with no word why."""
    out, insulators, _ = make_report(tmp_path)
    s = json.loads((out / "summary.json").read_text())
    s.update(run="replay", photos=[], photo_checks=None, inspections_skipped=[])
    for ins in s["insulators"]:
        ins["inspected"], ins["photos"] = False, []
    (out / "summary.json").write_text(json.dumps(s))
    write_report_html(out)
    text = (out / HTML_NAME).read_text(encoding="utf-8")
    assert 'id="replay-note"' in text and "A replay carries no photos of its own" in text
    assert text.count("found (a replay takes no photos)") == len(insulators)
    assert "found in a replay, which takes no photos" in text and ">no photo<" not in text
    assert 'fill="#d62728"' not in text  # no insulator marker red


def test_the_sensors_row_names_the_sensor_not_a_private_class():
    from insulator_rs.ports.sensors import sensors_name

    class _ClockedWrapper:
        pass

    class Named:
        name = "live: Livox Mid-360, camera rtsp://cam"

    assert sensors_name(_ClockedWrapper()) == "ClockedWrapper"
    assert sensors_name(Named()) == "live: Livox Mid-360, camera rtsp://cam"


def test_the_page_comes_from_autoescaped_templates_that_ship_in_the_package(tmp_path):
    """A designer edits templates/, not Python: the page's templates are package files, and a
    value from summary.json is escaped (autoescaping on), never markup."""
    from importlib import resources

    names = {p.name for p in resources.files("insulator_rs.report").joinpath("templates").iterdir()}
    assert {"report.html.j2", "photo.html.j2", "map.svg.j2", "report.css"} <= names
    out, _, _ = make_report(tmp_path)
    s = json.loads((out / "summary.json").read_text())
    s["status"] = "aborted: <b>heartbeat</b> lost"
    (out / "summary.json").write_text(json.dumps(s))
    text = write_report_html(out).path.read_text(encoding="utf-8")
    assert "aborted: &lt;b&gt;heartbeat&lt;/b&gt; lost" in text and "<b>heartbeat" not in text


def test_a_big_photo_is_thumbnailed_from_a_reduced_decode(tmp_path):
    """A photo several times the thumbnail's width is decoded at 1/2..1/8 (JPEG's own reduced
    decode); the page still gives its full size (from the JPEG header, EXIF before it), and the
    thumbnail matches a full decode scaled down by cv2 (mean difference under 3 counts)."""
    from insulator_rs.report.html import THUMB_WIDTH, _thumbnail

    w = ReportWriter(tmp_path / "r", origin=ORIGIN)
    big = cv2.resize(_photo(0), (2600, 1950), interpolation=cv2.INTER_CUBIC)
    rec = w.save_photo("big.jpg", big, time_utc=datetime(2026, 6, 1, 10, 0, tzinfo=timezone.utc),
                       position_enu=np.zeros(3), yaw_enu=0.0, gimbal_pitch=0.0)
    path = tmp_path / "r" / rec["file"]
    thumb, size, problem = _thumbnail(path)
    assert problem is None and size == (2600, 1950)
    got = cv2.imdecode(np.frombuffer(base64.b64decode(thumb.split(",", 1)[1]), np.uint8), cv2.IMREAD_COLOR)
    ref = cv2.resize(cv2.imread(str(path)), (THUMB_WIDTH, 240), interpolation=cv2.INTER_AREA)
    assert got.shape == ref.shape and float(np.abs(got.astype(float) - ref).mean()) < 3.0
