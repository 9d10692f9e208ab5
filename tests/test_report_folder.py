"""Report folders never describe one run with another run's files (issue 13 item 5).

A new run writes a new folder; an existing report is replaced only with ``--overwrite``,
and then only whole: killed (SIGKILL) at any point, ``--out`` holds either the old report
byte for byte or the new run's report whose summary says it did not finish. The kills are
real: a child process is SIGKILLed while it writes, and (slow) the ``inspect`` command is
SIGKILLed mid-flight and SIGINTed mid-flight.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import geojson
import numpy as np
import pymap3d
import pytest
from PIL import Image

import insulator_rs
from insulator_rs.app.cli import main
from insulator_rs.geodesy import GeoPoint
from insulator_rs.report import ReportWriter, check_out_folder
from insulator_rs.report import folder as folder_mod
from helpers.summaries import run_summary
from helpers.flights import ARGS, small_scene  # the small scene of the inspect tests (tests/ is on sys.path)

# where the insulator_rs under test was imported from (the source tree, or site-packages in CI)
PACKAGE_PARENT = Path(insulator_rs.__file__).resolve().parents[1]
ORIGIN = GeoPoint(49.5, 15.0, 420.0)
CHILD_TIMEOUT = 120.0  # s: a child that never reaches its checkpoint fails the test instead of hanging it


def _old_report(out: Path) -> dict[str, str]:
    """A finished report of an earlier run (made by the writer itself); its files' hashes."""
    w = ReportWriter(out, origin=ORIGIN)
    w.log_pose(0.0, np.zeros(3), 0.0, "idle")
    rec = w.save_photo("insulator_01_1.jpg", np.full((16, 16, 3), 200, np.uint8),
                       time_utc=w.opened_utc, position_enu=np.ones(3), yaw_enu=0.0)
    w.write_summary(run_summary("finished", marker="old run", photos=[{**rec, "position": [1.0, 1.0, 1.0]}]))
    w.close()
    return _hashes(out)


def _hashes(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _siblings(out: Path) -> list[Path]:
    return sorted(p for p in out.parent.iterdir() if p.name.startswith(f".{out.name}."))


def test_a_new_folder_says_running_before_anything_else(tmp_path):
    out = tmp_path / "a" / "report"
    w = ReportWriter(out, origin=ORIGIN)
    assert json.loads((out / "summary.json").read_text())["status"] == "running"
    assert w.layout.path == out and not w.layout.staged
    w.close()
    assert _siblings(out) == []


def test_an_existing_report_is_refused_without_overwrite(tmp_path):
    out = tmp_path / "report"
    before = _old_report(out)
    with pytest.raises(ValueError, match="--out: .* already holds files.*--overwrite"):
        ReportWriter(out, origin=ORIGIN)
    assert _hashes(out) == before and _siblings(out) == []
    (tmp_path / "empty").mkdir()
    ReportWriter(tmp_path / "empty", origin=ORIGIN).close()  # an empty folder is a new folder


def test_overwrite_refuses_what_is_not_a_report(tmp_path):
    notes = tmp_path / "notes"
    notes.mkdir()
    (notes / "todo.txt").write_text("keep me")
    with pytest.raises(ValueError, match="--out: .* no insulator_rs report"):
        check_out_folder(notes, overwrite=True)
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="--out: .* not a folder"):
        check_out_folder(tmp_path / "file", overwrite=True)
    cwd = Path.cwd()
    try:
        os.chdir(notes)
        (notes / "summary.json").write_text("{}")
        with pytest.raises(ValueError, match="--out: .* current folder"):
            check_out_folder(Path("."), overwrite=True)
    finally:
        os.chdir(cwd)
    assert (notes / "todo.txt").read_text() == "keep me"


def test_overwrite_keeps_the_old_report_whole_until_the_new_one_is_done(tmp_path):
    out = tmp_path / "report"
    before = _old_report(out)
    mode = out.stat().st_mode & 0o7777
    w = ReportWriter(out, origin=ORIGIN, overwrite=True)
    assert w.layout.staged and w.layout.path.parent == tmp_path and w.layout.path.name.startswith(".report.new-")
    w.save_photo("insulator_02_1.jpg", np.zeros((16, 16, 3), np.uint8), time_utc=w.opened_utc,
                 position_enu=np.zeros(3), yaw_enu=0.0)
    w.write_summary(run_summary("running", marker="new run"))
    assert _hashes(out) == before  # nothing of the new run in --out yet
    w.write_summary(run_summary("finished", marker="new run"))
    w.close()
    s = json.loads((out / "summary.json").read_text())
    assert s["detector"] == "new run" and s["status"] == "finished"
    assert sorted(p.name for p in (out / "images").iterdir()) == ["insulator_02_1.jpg"]
    assert _siblings(out) == []  # the old report is gone, no staging folder left
    assert out.stat().st_mode & 0o7777 == mode  # not the temporary folder's 0700


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="renameat2 RENAME_EXCHANGE is Linux-only")
def test_the_swap_is_one_atomic_exchange_on_linux(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    (a / "x").write_text("a")
    (b / "x").write_text("b")
    assert folder_mod._exchange(a, b)
    assert (a / "x").read_text() == "b" and (b / "x").read_text() == "a"


def test_the_fallback_without_exchange_still_replaces(tmp_path, monkeypatch):
    monkeypatch.setattr(folder_mod, "_exchange", lambda a, b: False)
    out = tmp_path / "report"
    _old_report(out)
    w = ReportWriter(out, origin=ORIGIN, overwrite=True)
    w.write_summary(run_summary("finished", marker="new run"))
    w.close()
    assert json.loads((out / "summary.json").read_text())["detector"] == "new run"
    assert _siblings(out) == [] and not (out / "images" / "insulator_01_1.jpg").exists()


CHILD = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    import numpy as np
    from insulator_rs.geodesy import GeoPoint
    from insulator_rs.report import ReportWriter
    from insulator_rs.report.summary import PerceptionRecord, RunSummary
    out, overwrite, ready = Path(sys.argv[1]), sys.argv[2] == "1", Path(sys.argv[3])
    w = ReportWriter(out, origin=GeoPoint(49.5, 15.0, 420.0), overwrite=overwrite)
    w.log_pose(0.0, np.zeros(3), 0.0, "explore")
    rec = w.save_photo("insulator_07_1.jpg", np.zeros((16, 16, 3), np.uint8), time_utc=w.opened_utc,
                       position_enu=np.zeros(3), yaw_enu=0.0)
    w.write_summary(RunSummary(run="flight", status="running", detector="new run", method="bounded",
                               flight_time_s=0.0, perception=PerceptionRecord(), insulators=[],
                               photos=[{**rec, "position": [0.0, 0.0, 0.0]}]))
    ready.write_text("photo written")
    while True:
        w.log_pose(0.0, np.zeros(3), 0.0, "explore")
        time.sleep(0.01)
""")


def _kill_child_after_first_photo(tmp_path: Path, out: Path, overwrite: bool) -> None:
    ready = tmp_path / "ready"
    env = {**os.environ, "PYTHONPATH": str(PACKAGE_PARENT)}
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(out), "1" if overwrite else "0", str(ready)],
                            env=env)
    try:
        t0 = time.monotonic()
        while not ready.exists():
            assert proc.poll() is None, f"the writer child exited early ({proc.returncode})"
            assert time.monotonic() - t0 < CHILD_TIMEOUT, "the writer child never wrote its photo"
            time.sleep(0.02)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=CHILD_TIMEOUT)
    assert proc.returncode == -signal.SIGKILL


def test_sigkill_mid_run_with_overwrite_leaves_the_old_report_whole(tmp_path):
    out = tmp_path / "report"
    before = _old_report(out)
    _kill_child_after_first_photo(tmp_path, out, overwrite=True)
    assert _hashes(out) == before  # the old report, byte for byte, its photo included
    (staged,) = _siblings(out)
    s = json.loads((staged / "summary.json").read_text())
    assert s["status"] == "running" and s["detector"] == "new run"  # the partial new run says so
    assert (staged / "images" / "insulator_07_1.jpg").is_file()
    # the next run names what the killed one left, deletes nothing of it, and replaces the old report
    w = ReportWriter(out, origin=ORIGIN, overwrite=True)
    assert w.layout.leftovers() == [staged]
    w.close()
    assert json.loads((out / "summary.json").read_text())["status"] == "running"  # the new run's
    assert _siblings(out) == [staged] and (staged / "images" / "insulator_07_1.jpg").is_file()


def test_sigkill_mid_run_into_a_new_folder_leaves_a_running_report(tmp_path):
    out = tmp_path / "report"
    _kill_child_after_first_photo(tmp_path, out, overwrite=False)
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "running" and [p["file"] for p in s["photos"]] == ["images/insulator_07_1.jpg"]
    assert (out / "images" / "insulator_07_1.jpg").is_file() and _siblings(out) == []


# -- the inspect command ------------------------------------------------------------------------

def test_inspect_refuses_an_empty_out(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["inspect", "--out", ""])
    assert exc.value.code == 2
    assert "argument --out: must name a report folder" in capsys.readouterr().err


def test_inspect_refuses_an_existing_report_before_flying(tmp_path, capsys):
    out = tmp_path / "report"
    before = _old_report(out)
    assert main(["inspect", "--out", str(out)]) == 2
    assert "--out: " in (err := capsys.readouterr().err) and "--overwrite" in err
    assert _hashes(out) == before and _siblings(out) == []


def _inspect_cmd(tmp_path: Path, out: Path, *extra: str) -> list[str]:
    scene, mission = small_scene(tmp_path)
    return [sys.executable, "-m", "insulator_rs.app.cli", "inspect", "--scene", str(scene), "--mission", str(mission),
            "--out", str(out), *ARGS, *extra]


def _run_until_first_photo(cmd: list[str], watch: Path, pattern: str) -> subprocess.Popen:
    """Start ``inspect`` and return once a photo matching ``watch.glob(pattern)`` exists."""
    env = {**os.environ, "PYTHONPATH": str(PACKAGE_PARENT)}
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    t0 = time.monotonic()
    while not list(watch.glob(pattern)):
        if proc.poll() is not None:
            raise AssertionError(f"inspect ended before its first photo: {proc.stderr.read().decode()[-2000:]}")
        if time.monotonic() - t0 > CHILD_TIMEOUT:
            proc.kill()
            raise AssertionError("inspect took no photo in time")
        time.sleep(0.05)
    return proc


@pytest.mark.slow
def test_inspect_killed_mid_flight_with_overwrite_keeps_the_old_report(tmp_path):
    out = tmp_path / "report"
    before = _old_report(out)
    proc = _run_until_first_photo(_inspect_cmd(tmp_path, out, "--overwrite"), tmp_path,
                                  ".report.new-*/images/*.jpg")
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=CHILD_TIMEOUT)
    assert _hashes(out) == before
    (staged,) = _siblings(out)
    s = json.loads((staged / "summary.json").read_text())
    assert s["status"] == "running"
    assert all((staged / p["file"]).is_file() for p in s["photos"])


@pytest.mark.slow
def test_inspect_interrupted_with_overwrite_replaces_with_the_interrupted_run(tmp_path):
    """Ctrl-C in the air is the operator's abort (the safe route, then the landing: exit 1); the
    run it ended replaces the old report as a finished one would."""
    out = tmp_path / "report"
    _old_report(out)
    proc = _run_until_first_photo(_inspect_cmd(tmp_path, out, "--overwrite"), tmp_path,
                                  ".report.new-*/images/*.jpg")
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=CHILD_TIMEOUT) == 1
    s = json.loads((out / "summary.json").read_text())
    assert s["status"].startswith("aborted: operator: Ctrl-C"), s["status"]
    assert s["detector"] != "new run" and len(s["photos"]) >= 1
    assert sorted(f"images/{p.name}" for p in (out / "images").iterdir()) == sorted(p["file"] for p in s["photos"])
    assert _siblings(out) == []
    _check_deliverables(out, s)


def _check_deliverables(out: Path, s: dict) -> None:
    """The inspect command's photos carry EXIF GPS of the pose it logged (pymap3d from the summary's
    origin: 1e-8 deg, 1 mm; heading 90 - yaw to 0.006 deg) and its GeoJSON validates."""
    o = s["origin"]
    for p in s["photos"]:
        gps = Image.open(out / p["file"]).getexif().get_ifd(0x8825)
        lat, lon, alt = pymap3d.enu2geodetic(*p["position"], o["lat"], o["lon"], o["alt"])
        got_lat = sum(float(v) / 60 ** k for k, v in enumerate(gps[2])) * (1 if gps[1] == "N" else -1)
        got_lon = sum(float(v) / 60 ** k for k, v in enumerate(gps[4])) * (1 if gps[3] == "E" else -1)
        assert abs(got_lat - lat) < 1e-8 and abs(got_lon - lon) < 1e-8 and abs(float(gps[6]) - alt) < 1e-3
        heading = (90.0 - np.degrees(p["yaw"])) % 360.0
        assert min(abs(float(gps[17]) - heading), 360 - abs(float(gps[17]) - heading)) < 0.006
    doc = geojson.loads((out / "inspection.geojson").read_text())
    assert doc.is_valid, doc.errors()
    kinds = [f["properties"]["kind"] for f in doc["features"]]
    assert kinds.count("photo") == len(s["photos"]) and kinds.count("insulator") == len(s["insulators"])
    assert kinds.count("flight_path") == 1


def test_the_flown_distance_is_summed_as_poses_come(tmp_path):
    # Reference: numpy's sum of the step lengths of the whole trajectory, the summary's former
    # computation (it copied the trajectory every 5 s; now the writer sums as poses come).
    rng = np.random.default_rng(3)
    path = np.cumsum(rng.normal(0.0, 0.4, (500, 3)), axis=0)
    w = ReportWriter(tmp_path / "out", origin=ORIGIN)
    assert w.distance_m == 0.0
    for k, p in enumerate(path):
        w.log_pose(0.02 * k, p, 0.0, "explore")
    w.close()
    assert w.distance_m == pytest.approx(float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1))), rel=1e-12)
