"""The dependency rules of ARCHITECTURE.md, checked: no onboard module loads the simulator.

Every module of the package except the simulator's adapters, the evaluation (which reads
ground truth after a flight) and the composition roots is imported in a fresh interpreter,
and ``sys.modules`` must then hold no ``insulator_rs.sim`` module. The list is found by
walking the package, so a new onboard module is covered without editing this test.
"""

from __future__ import annotations

import json
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import insulator_rs

PYTHON_DIR = Path(insulator_rs.__file__).resolve().parents[1]

# What may import the simulator (ARCHITECTURE.md, "Dependency rules"), by module-name prefix.
ALLOWED_TO_USE_SIM = (
    "insulator_rs.sim",  # the simulator's own adapters
    "insulator_rs.evaluation",  # scorer and studies: ground truth, after a flight
    "insulator_rs.app.inspect_command",  # composition root: wires the adapters a run asks for
    "insulator_rs.app.cli",  # composition root: registers every command
)
# Offline tools with heavy optional dependencies, not part of the flying software.
OFFLINE_TOOLS = ("insulator_rs.detection.train", "insulator_rs.app.train_command")


def onboard_modules() -> list[str]:
    names = []
    for info in pkgutil.walk_packages([str(PYTHON_DIR / "insulator_rs")], prefix="insulator_rs."):
        name = info.name
        if name.startswith(ALLOWED_TO_USE_SIM) or name in OFFLINE_TOOLS:
            continue
        names.append(name)
    return sorted(names)


def test_the_walk_covers_every_onboard_layer() -> None:
    names = set(onboard_modules())
    for required in ("insulator_rs._core", "insulator_rs.ports.vehicle", "insulator_rs.ports.sensors",
                     "insulator_rs.exceptions", "insulator_rs.rig", "insulator_rs.poses",
                     "insulator_rs.flight.loop", "insulator_rs.ports.detector",
                     "insulator_rs.perception.pipeline", "insulator_rs.mission.state_machine",
                     "insulator_rs.mavlink.client", "insulator_rs.mavlink.frames",
                     "insulator_rs.detection.detector"):
        assert required in names, required


def test_no_onboard_module_imports_the_simulator() -> None:
    modules = onboard_modules()
    code = (
        "import importlib, json, sys\n"
        f"for name in {modules!r}:\n"
        "    importlib.import_module(name)\n"
        "print(json.dumps(sorted(m for m in sys.modules if m == 'insulator_rs.sim' "
        "or m.startswith('insulator_rs.sim.'))))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(PYTHON_DIR)})
    assert done.returncode == 0, done.stderr
    loaded = json.loads(done.stdout.strip().splitlines()[-1])
    assert loaded == [], f"onboard modules loaded the simulator: {loaded}"


def test_the_check_would_see_a_simulator_import() -> None:
    """The same probe, on a module that does import the simulator, reports it (the test can fail)."""
    code = ("import sys, insulator_rs.app.inspect_command\n"
            "print(any(m.startswith('insulator_rs.sim') for m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(PYTHON_DIR)})
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "True"
