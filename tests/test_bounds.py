"""Mission, scene and CLI bounds (insulator_rs.bounds): hostile values are refused
before anything flies, with the file and the field (or the flag) named; no traceback, no hang.

Each case here used to fly (issue 13 items 3 and 7): ``max_height = 1e300`` and
``pass_spacing = 1e-9`` planned forever, ``waypoints_per_insulator = 1e9`` ran out of memory
mid-flight, a take-off point 111 km away crashed after take-off, ``--v-max 1e6`` hung,
``panels = 1e8`` hung the mesh builder, ``registry_gate = 1e9`` silently found nothing.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

import insulator_rs
from insulator_rs._toml import tomllib
from insulator_rs.exceptions import ConfigError
from insulator_rs import bounds
from insulator_rs.mission.config import load_mission, parse_mission
from insulator_rs.sim.scene import SceneError, load_scene, parse_scene

ROOT = Path(__file__).resolve().parents[1]
# where the insulator_rs under test was imported from (the source tree, or site-packages in CI)
PACKAGE_PARENT = Path(insulator_rs.__file__).resolve().parents[1]
PACKAGE = ROOT / "python" / "insulator_rs"
MISSION_A = PACKAGE / "missions" / "tower_a.toml"
SCENE_A = PACKAGE / "scenes" / "tower_a.toml"
CLI_TIMEOUT = 120  # s; a refused option returns in seconds, the old hangs never returned


def _mission() -> dict:
    return tomllib.loads(MISSION_A.read_text())


def _scene() -> dict:
    return tomllib.loads(SCENE_A.read_text())


# A 111 km take-off point: one degree of latitude north of tower A.
TAKEOFF_FAR = {"lat": 51.0, "lon": 14.0, "alt": 300.0}

MISSION_CASES = [
    ("tower", "max_height", 1e300, "tower.max_height: must lie in (0, 400] m"),
    ("tower", "max_height", 10**400, "tower.max_height: must be finite, got an integer of 401 digits"),
    ("inspection", "pass_spacing", 1e-9, "inspection.pass_spacing: must lie in [0.5, 40] m"),
    ("inspection", "waypoints_per_insulator", 10**9, "inspection.waypoints_per_insulator: must lie in [1, 12]"),
    ("inspection", "insulator_length", 1e9, "inspection.insulator_length: must lie in [0.1, 15] m"),
    ("inspection", "standoff", 1e300, "inspection.standoff: must lie in (0, 40] m"),
    ("inspection", "registry_gate", 1e9, "inspection.registry_gate: must lie in (0, 3] m"),
    ("inspection", "confirmations", 10**6, "inspection.confirmations: must lie in [1, 20]"),
    ("vehicle", "v_max_horizontal", 1e-300, "vehicle.v_max_horizontal: must lie in [0.1, 10] m/s"),
    ("vehicle", "a_max_vertical", 1e6, "vehicle.a_max_vertical: must lie in [0.1, 20] m/s^2"),
    ("tower", "alt", 1e7, "tower.alt: must lie in [-500, 9000] m"),
]


@pytest.mark.parametrize("table, key, value, message", MISSION_CASES,
                         ids=[f"{t}.{k}={v if not isinstance(v, int) or v < 1e12 else 'huge'}"
                              for t, k, v, _ in MISSION_CASES])
def test_mission_values_beyond_physics_are_refused(table, key, value, message):
    data = _mission()
    data[table][key] = value
    with pytest.raises(ConfigError, match=f"^m.yaml: {re.escape(message)}"):
        parse_mission(data, "m.yaml")


def test_takeoff_far_from_the_tower_is_refused():
    data = _mission()
    data["takeoff"] = TAKEOFF_FAR
    with pytest.raises(ConfigError, match=r"^m.toml: takeoff: horizontal distance from the tower "
                                          r"must lie in \[0, 500\] m .*got 111"):
        parse_mission(data, "m.toml")
    data["takeoff"] = {"lat": 50.0002, "lon": 14.0, "alt": 900.0}
    with pytest.raises(ConfigError, match=r"takeoff.alt: height above the tower base must lie in"):
        parse_mission(data, "m.toml")


def test_neighbour_beyond_the_longest_span_is_refused():
    data = _mission()
    data["neighbours"][0]["lat"] = 49.9  # 11 km south
    with pytest.raises(ConfigError, match=r"neighbours\[0\]: horizontal distance from the tower "
                                          r"must lie in \[10, 6000\] m"):
        parse_mission(data, "m.toml")


def test_values_at_the_limits_are_accepted():
    """Both ends of every mission limit load (the bounds refuse mistakes, not real missions)."""
    for field, limit in bounds.MISSION.items():
        table, key = field.split(".")
        for value in (limit.hi, limit.lo if not limit.lo_open else limit.lo + 0.01):
            data = _mission()
            if table == "neighbours":
                for nb in data["neighbours"]:
                    nb[key] = value
            elif table == "takeoff":
                continue  # the take-off altitude is bound to the tower's (TAKEOFF_HEIGHT)
            else:
                data[table][key] = int(value) if limit.integer else value
            if key == "alt" and table == "tower":
                for nb in data["neighbours"]:
                    nb["alt"] = value
            if key == "safety_margin":
                data["inspection"]["standoff"] = 40.0
            if key == "standoff" and value < 2.5:
                data["inspection"]["safety_margin"] = 0.0
            mission = parse_mission(data, "m.toml")
            assert mission is not None


def test_yaml_huge_integer_is_refused_by_load(tmp_path):
    text = yaml.safe_dump(_mission()).replace("max_height: 31.0", "max_height: 1" + "0" * 400)
    assert "0" * 400 in text
    path = tmp_path / "huge.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"huge.yaml: tower.max_height: must be finite"):
        load_mission(path)


def test_unreadable_mission_files_name_the_file(tmp_path):
    binary = tmp_path / "binary.toml"
    binary.write_bytes(bytes(range(256)))
    with pytest.raises(ConfigError, match=r"binary.toml: <file>: not UTF-8 text \(byte 0x80 at offset 128\)"):
        load_mission(binary)
    latin = tmp_path / "latin.yaml"
    latin.write_bytes(MISSION_A.read_text().replace("# the paper", "# Ströme").encode("latin-1"))
    with pytest.raises(ConfigError, match=r"latin.yaml: <file>: not UTF-8 text"):
        load_mission(latin)
    folder = tmp_path / "folder.toml"
    folder.mkdir()
    with pytest.raises(ConfigError, match=r"folder.toml: <file>: is a directory, not a file"):
        load_mission(folder)
    with pytest.raises(ConfigError, match=r"absent.toml: <file>: no such file"):
        load_mission(tmp_path / "absent.toml")
    big = tmp_path / "big.toml"
    big.write_bytes(b"#" * (2 << 20))
    with pytest.raises(ConfigError, match=r"big.toml: <file>: file too large"):
        load_mission(big)


def test_yaml_constructor_errors_name_the_file(tmp_path):
    path = tmp_path / "date.yaml"
    path.write_text("tower: 2001-02-30\n")  # PyYAML raises ValueError (day out of range)
    with pytest.raises(ConfigError, match=r"date.yaml: <file>: cannot parse"):
        load_mission(path)
    path.write_text("{1: 2, a: 3}\n")  # keys that do not sort together
    with pytest.raises(ConfigError, match=r"date.yaml: <root>\.1: unknown field"):
        load_mission(path)


SCENE_CASES = [
    ("body", "panels", 10**8, r"body\.panels': must lie in \[1, 100\]"),
    ("body", "height", 1e4, r"body\.height': must lie in \(0, 400\] m"),
    ("insulators", "sheds", 10**7, r"insulators\.sheds': must lie in \[2, 300\]"),
    ("conductors", "segment_length", 1e-6, r"conductors\.segment_length': must lie in \[0.05, 1000\] m"),
    ("conductors", "modelled_length", 1e9, r"conductors\.modelled_length': must lie in"),
    (None, "ground_size", 1e12, r"ground_size': must lie in \(0, 10000\] m"),
]


@pytest.mark.parametrize("table, key, value, message", SCENE_CASES,
                         ids=[f"{t}.{k}" for t, k, _, _ in SCENE_CASES])
def test_scene_values_beyond_physics_are_refused(table, key, value, message):
    data = _scene()
    (data[table] if table else data)[key] = value
    with pytest.raises(SceneError, match=f"^s.toml: field '{message}"):
        parse_scene(data, "s.toml")


def test_scene_counts_and_neighbours_are_bounded():
    data = _scene()
    data["cross_arms"] = data["cross_arms"] * 20
    with pytest.raises(SceneError, match=r"field 'cross_arms': at most 12 tables"):
        parse_scene(data, "s.toml")
    data = _scene()
    data["neighbours"][0] = [0.0, -1e7, 0.0]
    with pytest.raises(SceneError, match=r"field 'neighbours\[0\]': each coordinate must lie in"):
        parse_scene(data, "s.toml")
    data = _scene()
    data["conductors"]["segment_length"] = 0.05  # 80 m / 0.05 m = 1600 segments: allowed
    assert parse_scene(data, "s.toml").conductors.segment_length == 0.05
    data["conductors"]["modelled_length"] = 1000.0  # 20000 segments
    with pytest.raises(SceneError, match=r"conductors\.segment_length': modelled_length / segment_length"):
        parse_scene(data, "s.toml")


def test_scene_files_that_are_not_text_or_not_files(tmp_path):
    folder = tmp_path / "folder.toml"
    folder.mkdir()
    with pytest.raises(SceneError, match=r"folder.toml: is a directory"):
        load_scene(folder)
    binary = tmp_path / "b.toml"
    binary.write_bytes(b"\xff\xfe\x00name")
    with pytest.raises(SceneError, match=r"b.toml: not UTF-8 text"):
        load_scene(binary)


def test_option_types_refuse_and_accept():
    import argparse

    v_max = bounds.option("--v-max")
    assert v_max("2.5") == 2.5 and v_max("0.5") == 0.5 and v_max("0.1") == 0.1
    for text in ("1e6", "25", "0.05", "nan", "inf", "0", "-1", "fast"):
        with pytest.raises(argparse.ArgumentTypeError):
            v_max(text)
    seed = bounds.option("--seed")
    assert seed("0") == 0 and seed(str(2**32 - 1)) == 2**32 - 1
    for text in ("-1", "1.5", str(2**32)):
        with pytest.raises(argparse.ArgumentTypeError):
            seed(text)


# ---- the command line, as a user runs it --------------------------------------------------

def _write_mission(tmp_path: Path, name: str, mutate) -> Path:
    data = _mission()
    mutate(data)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def _cli_cases(tmp_path: Path) -> dict[str, tuple[list[str], list[str]]]:
    """name -> (arguments after ``inspect``, fragments the error must contain)."""
    folder = tmp_path / "dir.yaml"
    folder.mkdir()
    binary = tmp_path / "bin.toml"
    binary.write_bytes(bytes(range(256)) * 4)
    huge = tmp_path / "huge.yaml"
    huge.write_text(yaml.safe_dump(_mission()).replace("max_height: 31.0", "max_height: 1" + "0" * 400))
    return {
        "v-max 1e6": (["--v-max", "1e6"], ["argument --v-max: must lie in [0.1, 10] m/s"]),
        "v-max nan": (["--v-max", "nan"], ["argument --v-max:", "got nan"]),
        "detect-period 0": (["--detect-period", "0"], ["argument --detect-period: must lie in"]),
        "seed -1": (["--seed", "-1"], ["argument --seed: must lie in [0, 4294967295]"]),
        "max_height 1e300": (["--mission", str(_write_mission(
            tmp_path, "tall.yaml", lambda d: d["tower"].update(max_height=1e300)))],
            ["tall.yaml: tower.max_height: must lie in"]),
        "pass_spacing 1e-9": (["--mission", str(_write_mission(
            tmp_path, "dense.yaml", lambda d: d["inspection"].update(pass_spacing=1e-9)))],
            ["dense.yaml: inspection.pass_spacing: must lie in"]),
        "takeoff 111 km": (["--mission", str(_write_mission(
            tmp_path, "far.yaml", lambda d: d.update(takeoff=TAKEOFF_FAR)))],
            ["far.yaml: takeoff: horizontal distance from the tower must lie in"]),
        "max_height 10**400": (["--mission", str(huge)], ["huge.yaml: tower.max_height: must be finite"]),
        "binary mission": (["--mission", str(binary)], ["bin.toml: <file>: not UTF-8 text"]),
        "directory mission": (["--mission", str(folder)], ["dir.yaml: <file>: is a directory"]),
    }


@pytest.mark.slow
def test_cli_refuses_hostile_options_and_files_before_flight(tmp_path):
    """``insulator-rs inspect`` as a subprocess (concurrently, each under a timeout): status 2,
    the flag or the file and field named on stderr, no traceback, no report folder."""
    env = {**os.environ, "PYTHONPATH": str(PACKAGE_PARENT)}
    cases = _cli_cases(tmp_path)
    runs = {}
    for name, (args, _) in cases.items():
        out = tmp_path / f"out-{name.replace(' ', '_')}"
        cmd = [sys.executable, "-m", "insulator_rs.app.cli", "inspect", "--quiet", "--out", str(out), *args]
        runs[name] = (out, subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                            text=True, env=env))
    failures = []
    for name, (out, proc) in runs.items():
        try:
            _, err = proc.communicate(timeout=CLI_TIMEOUT)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            failures.append(f"{name}: still running after {CLI_TIMEOUT} s")
            continue
        fragments = cases[name][1]
        if proc.returncode != 2 or "Traceback" in err or not all(f in err for f in fragments) or out.exists():
            failures.append(f"{name}: rc {proc.returncode}, report folder {out.exists()}, stderr:\n{err[-800:]}")
    assert not failures, "\n\n".join(failures)


@pytest.mark.parametrize("argv, flag", [
    (["eval", "localization", "--false-positives", "1e9"], "--false-positives"),  # was killed at 24 GB
    (["eval", "localization", "--seed", "-1"], "--seed"),
    (["detect", "run", "--threads", "100000", "x.png"], "--threads"),  # was 23k threads, 16.8 GB
])
def test_runaway_counts_are_refused(argv, flag, capsys):
    from insulator_rs.app.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    assert f"argument {flag}: must lie in" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [
    ["eval", "localization", "--out", ""],
    ["eval", "efficiency", "--out", " "],
    ["dataset", "--out", ""],
    ["train", "--out", "", "--data", "x"],
])
def test_empty_out_folder_is_refused(argv, capsys):
    """``--out ''`` used to write into the current folder (issue 13 item 7)."""
    from insulator_rs.app.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    assert "argument --out: must name a report folder" in capsys.readouterr().err
