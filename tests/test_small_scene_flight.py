"""scripts/small_scene_flight.py compare: CI's check that the aarch64 wheel (under qemu) flies
the small scene as the x86-64 wheel does. Its reports here are written by hand in the shape
of inspect's summary.json; .ci/run compares two real flights."""

from __future__ import annotations

import copy
import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("small_scene_flight", ROOT / "scripts" / "small_scene_flight.py")
assert _spec is not None and _spec.loader is not None
flight = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(flight)

SUMMARY = {
    "status": "finished", "insulators_found": 2, "insulators_inspected": 2,
    "photos": [{"file": "images/insulator_01_1.jpg"}, {"file": "images/insulator_02_1.jpg"}],
    "insulators": [{"id": 1, "center": [2.390364200072474, -1.7930483295856434, 8.995746123259417]},
                   {"id": 2, "center": [-2.391, 1.794, 8.990]}],
}


def _write(folder: Path, summary: dict) -> Path:
    (folder / "report").mkdir(parents=True)
    (folder / "report" / "summary.json").write_text(json.dumps(summary))
    return folder


def test_the_same_flight_agrees(tmp_path: Path) -> None:
    a = _write(tmp_path / "a", SUMMARY)
    b = copy.deepcopy(SUMMARY)
    b["insulators"][0]["center"][0] += 1e-11  # the rounding measured between the CPUs
    assert flight.compare(a, _write(tmp_path / "b", b)) == []
    assert flight.main(["compare", str(a), str(tmp_path / "b")]) == 0


@pytest.mark.parametrize("change, expected", [
    (lambda s: s["insulators"][1]["center"].__setitem__(2, 9.02), "insulator 2: centres 0.0300 m apart"),
    (lambda s: s.__setitem__("insulators_found", 1), "insulators_found: 2"),
    (lambda s: s["insulators"].pop(), "2 insulators in"),
    (lambda s: s["photos"].pop(), "the photos taken differ"),
    (lambda s: s.__setitem__("status", "aborted"), "status: 'finished'"),
])
def test_a_difference_is_named(tmp_path: Path, change, expected: str) -> None:  # type: ignore[no-untyped-def]
    b = copy.deepcopy(SUMMARY)
    change(b)
    problems = flight.compare(_write(tmp_path / "a", SUMMARY), _write(tmp_path / "b", b))
    assert any(expected in p for p in problems), problems
    assert flight.main(["compare", str(tmp_path / "a"), str(tmp_path / "b")]) == 1


@pytest.mark.parametrize("content", [None, "{not json", json.dumps({"status": "finished"}), "[1, 2]"])
def test_a_missing_or_bad_report_is_refused_by_path(tmp_path: Path, capsys, content) -> None:  # type: ignore[no-untyped-def]
    a = _write(tmp_path / "a", SUMMARY)
    b = tmp_path / "b"
    if content is not None:
        (b / "report").mkdir(parents=True)
        (b / "report" / "summary.json").write_text(content)
    assert flight.main(["compare", str(a), str(b)]) == 2
    assert str(b / "report" / "summary.json") in capsys.readouterr().err
