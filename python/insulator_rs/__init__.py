"""insulator_rs: onboard insulator detection, localization and inspection planning for UAVs.

The heavy geometry lives in the compiled extension ``insulator_rs._core`` (Rust);
this package re-exports its public API and adds the Python orchestration.
"""

from __future__ import annotations

from insulator_rs._core import (
    NEAR_LIMIT,
    NOISE,
    SCALE_TOLERANCE,
    AmbiguousLocalizationError,
    CameraModel,
    LineFit,
    Localization,
    LocalizationError,
    InsulatorString,
    Pca,
    chain_transforms,
    dbscan,
    deskew,
    deskew_points_in_boxes,
    find_insulator_strings,
    localize,
    localize_bounded,
    localize_defaults,
    localize_methods,
    pca,
    points_in_boxes,
    project_points,
    ransac_line,
)
from insulator_rs.calibration import load_camera_model

__all__: list[str] = [
    "NEAR_LIMIT",
    "NOISE",
    "SCALE_TOLERANCE",
    "AmbiguousLocalizationError",
    "CameraModel",
    "InsulatorString",
    "LineFit",
    "Localization",
    "LocalizationError",
    "Pca",
    "chain_transforms",
    "dbscan",
    "deskew",
    "deskew_points_in_boxes",
    "find_insulator_strings",
    "load_camera_model",
    "localize",
    "localize_bounded",
    "localize_defaults",
    "localize_methods",
    "pca",
    "points_in_boxes",
    "project_points",
    "ransac_line",
]
