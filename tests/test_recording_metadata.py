"""A recording's mission names its rig file relative to where the mission was flown from
(`inspect --record`): a replay elsewhere (another folder, another machine) must still find
the rig and its calibration files, or say by name which file it cannot find.

Reference: the same rig file loaded directly (``insulator_rs.rig.load_rig``)."""

import shutil
from pathlib import Path

import numpy as np
import pytest

import insulator_rs
from insulator_rs.exceptions import ConfigError
from insulator_rs.recording.metadata import FlightMetadata
from insulator_rs.rig import load_rig

RIGS = Path(insulator_rs.__file__).resolve().parent / "rigs"
MISSION = Path(insulator_rs.__file__).resolve().parent / "missions" / "tower_b.toml"
RIG_FILES = ("simulator.toml", "simulator_camera.yaml", "simulator_inspection_camera.yaml")


def _flown_from(folder: Path) -> FlightMetadata:
    """The metadata `inspect --record` writes for a mission in ``folder`` naming a rig file of
    its own (``airframe.toml`` beside it, the way a crew's rig is a file, not a shipped name)."""
    folder.mkdir(parents=True, exist_ok=True)
    _copy_rig(folder)
    text = MISSION.read_text().replace('rig = "simulator"', 'rig = "airframe.toml"')
    assert 'rig = "airframe.toml"' in text
    mission = folder / "mission.toml"
    mission.write_text(text)
    return FlightMetadata(mission_text=text, mission_suffix=".toml", mission_source=str(mission.resolve()))


def _copy_rig(folder: Path) -> None:
    shutil.copy(RIGS / "simulator.toml", folder / "airframe.toml")
    for name in RIG_FILES[1:]:
        shutil.copy(RIGS / name, folder / name)


def test_the_rig_is_found_where_the_mission_was_flown_from(tmp_path, monkeypatch):
    meta = _flown_from(tmp_path / "flight")
    elsewhere = tmp_path / "replays"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # a replay run from another folder
    mission = meta.mission(tmp_path / "archive" / "flight.mcap")
    assert mission is not None and mission.rig is not None
    reference = load_rig(RIGS / "simulator.toml")
    assert mission.rig.camera.fx == reference.camera.fx and mission.rig.camera.width == reference.camera.width


def test_the_rig_beside_the_recording_when_the_flight_folder_is_gone(tmp_path):
    meta = _flown_from(tmp_path / "flight")
    shutil.rmtree(tmp_path / "flight")  # the recording copied to another machine, with its rig files
    archive = tmp_path / "archive"
    archive.mkdir()
    _copy_rig(archive)
    mission = meta.mission(archive / "flight.mcap")
    assert mission is not None and mission.rig is not None
    assert mission.rig.camera.fx == load_rig(RIGS / "simulator.toml").camera.fx


def test_a_rig_found_nowhere_is_refused_by_name(tmp_path):
    meta = _flown_from(tmp_path / "flight")
    shutil.rmtree(tmp_path / "flight")
    with pytest.raises(ConfigError, match=r"vehicle\.rig.*airframe\.toml"):
        meta.mission(tmp_path / "archive" / "flight.mcap")


# -- takeoff = "home": the recording keeps where the flight took off -------------------------------

def _home_mission_text() -> str:
    return 'takeoff = "home"\n' + MISSION.read_text()


def test_a_home_takeoff_survives_the_mcap_record_and_moves_the_replays_mission(tmp_path):
    """Reference: the home point itself (a GeoPoint 13 m out from the default take-off point,
    converted with pymap3d by the mission), written by McapRecorder and read back by read_metadata."""
    from insulator_rs.geodesy import enu_to_gps, gps_to_enu
    from insulator_rs.mission.config import parse_mission
    from insulator_rs.recording.metadata import RECORD_NAME, read_metadata, takeoff_record
    from insulator_rs.recording.writer import McapRecorder
    from insulator_rs._toml import tomllib

    text = _home_mission_text()
    planned = parse_mission(tomllib.loads(text), "home.toml")
    default = planned.takeoff_enu()
    where = default + np.array([3.0, -12.0, 0.4])
    flown = planned.with_takeoff(enu_to_gps(where, planned.tower))
    recording = tmp_path / "flight.mcap"
    recorder = McapRecorder(recording)
    recorder.metadata(RECORD_NAME, FlightMetadata(mission_text=text, mission_suffix=".toml",
                                                  mission_source=str(MISSION), takeoff=takeoff_record(flown)).as_record())
    recorder.close()
    meta = read_metadata(recording)
    assert meta.flown_takeoff() == flown.takeoff  # every digit kept
    replayed = meta.mission(recording)
    assert replayed is not None and replayed.takeoff == flown.takeoff
    assert np.allclose(replayed.takeoff_enu(), where, atol=1e-6)
    assert np.allclose(gps_to_enu(replayed.takeoff, replayed.tower), where, atol=1e-6)
    # --mission: a home mission given for the replay takes off there too; one naming its own does not
    assert meta.at_flown_takeoff(planned).takeoff == flown.takeoff
    plain = parse_mission(tomllib.loads(MISSION.read_text()), "plain.toml")
    assert meta.at_flown_takeoff(plain) is plain
    assert takeoff_record(plain) == "" and takeoff_record(planned) == ""  # no home to keep


def test_a_recording_without_the_home_plans_from_the_default_point_and_a_bad_one_is_named(tmp_path):
    old = FlightMetadata(mission_text=_home_mission_text(), mission_suffix=".toml", mission_source=str(MISSION))
    mission = old.mission(tmp_path / "flight.mcap")
    assert mission is not None and mission.takeoff_home and mission.takeoff is None
    bad = FlightMetadata(mission_text=_home_mission_text(), mission_suffix=".toml", mission_source=str(MISSION),
                         takeoff="49.5,15.0")
    with pytest.raises(ConfigError, match=r"the recording's takeoff: expected 'lat,lon,alt', got '49.5,15.0'"):
        bad.mission(tmp_path / "flight.mcap")
