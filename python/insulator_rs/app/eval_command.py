"""``insulator-rs eval <study>``: each study module exposes ``add_arguments(parser)``
and ``run(args) -> int``; they are imported only when their study runs."""

from __future__ import annotations

import argparse

from insulator_rs.app.cli import import_optional

# (study name, module, one-line help)
STUDIES: tuple[tuple[str, str, str], ...] = (
    ("localization", "insulator_rs.evaluation.localization_study",
     "localization error of the four methods on towers A and B (paper Tables I and II)"),
    ("airframe", "insulator_rs.evaluation.airframe_study",
     "localization on the tilting airframe in wind and braking: full attitude vs the level assumption"),
    ("efficiency", "insulator_rs.evaluation.efficiency_study",
     "single-flight vs two-flight inspection time (paper efficiency figure)"),
    ("motion", "insulator_rs.evaluation.motion_study",
     "localization error under motion distortion, with and without deskew"),
    ("faults", "insulator_rs.evaluation.fault_matrix",
     "the fault matrix: every fault at every moment of the flight, clearance to the true tower"),
    ("photo-check", "insulator_rs.evaluation.photo_check_study",
     "the photo check against the ground truth: good photos called unfit, gimbal/zoom/blur ones fit"),
    ("degraded-camera", "insulator_rs.evaluation.degraded_camera_study",
     "whole flights with a hazed camera or most true boxes dropped: camera only vs camera + LiDAR cue"),
)


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser("eval", help="run an evaluation study")
    studies = parser.add_subparsers(dest="study", required=True)
    for name, module_name, help_text in STUDIES:
        study_parser = studies.add_parser(name, help=help_text)
        module = import_optional(module_name)
        if module is None:
            continue
        module.add_arguments(study_parser)
        study_parser.set_defaults(func=module.run)
