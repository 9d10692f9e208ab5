"""A recording's mission names its rig file relative to where the mission was flown from
(`inspect --record`): a replay elsewhere (another folder, another machine) must still find
the rig and its calibration files, or say by name which file it cannot find.

Reference: the same rig file loaded directly (``insulator_rs.rig.load_rig``)."""

import shutil
from pathlib import Path

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
