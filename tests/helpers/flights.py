"""The small scene and the arguments the flight tests share (one cross-arm, two insulators)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from insulator_rs.evaluation import fault_matrix

REPO = Path(__file__).resolve().parents[2]
SCENES = REPO / "python" / "insulator_rs" / "scenes"
MISSIONS = REPO / "python" / "insulator_rs" / "missions"


def small_scene(tmp_path):
    """Tower B's design cut down to a 12 m body with one cross-arm (two insulators): the fault
    matrix's scene (``insulator_rs.evaluation.fault_matrix.small_scene``), files in ``tmp_path``."""
    return fault_matrix.small_scene(tmp_path, SCENES, MISSIONS)


# Detection twice a second: the false-find filter judges a string's shape on its first three
# localizations, and at 3 m/s a 1 Hz pass saw the far string only three times (12-16 points each).
ARGS = ["--detect-period", "0.5", "--detect-scale", "0.2", "--photo-scale", "0.2", "--quiet",
        "--detector", "standin"]  # flight logic under test: the ground-truth stand-in, named



# A distribution pole beside the small scene's far-side pass (1 m across from its line, 15 m
# high), outside the tower's safety box and conductor corridors: the tower model does not hold it.
# Append POLE to the scene file.
POLE_START = np.array([-8.0, 6.0, 0.0])
POLE_END = np.array([-8.0, 6.0, 15.0])
POLE_RADIUS = 0.15
POLE = f"""
[[obstacles]]
name = "distribution pole"
start = {POLE_START.tolist()}
end = {POLE_END.tolist()}
radius = {POLE_RADIUS}
"""
