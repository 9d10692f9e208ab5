"""Detection models shipped with the package, each an ONNX file with its model card.

``<name>.onnx`` is the Ultralytics export, ``<name>.json`` its card (data,
split, epochs, input size, metrics, training time) and ``<name>.md`` the same
card for people. Load one with ``Detector.from_name(name)``.
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path
from typing import Any

_PACKAGE = "insulator_rs.models"

# The shipped networks, by name: their one home (the CLI defaults and the ports refer to these).
SIMULATOR_MODEL = "insulator-sim"  # trained on rendered images: the simulator's camera
REAL_PHOTO_MODEL = "insulator-field"  # trained on field photos at the camera's geometry: real cameras
REAL_CROP_MODEL = "insulator-real"  # trained on the exported (stretched, rotated) photo set: `detect` default


def _folder() -> Path:
    return Path(str(resources.files(_PACKAGE)))


def available_models() -> list[str]:
    """Names of the shipped models (those with an ONNX file)."""
    return sorted(p.stem for p in _folder().glob("*.onnx"))


def model_path(name: str) -> Path:
    """Path of the shipped model ``name`` (e.g. ``"insulator-real"``).

    Raises ValueError naming the shipped models when there is none by that name.
    """
    path = _folder() / f"{name}.onnx"
    if not path.is_file():
        raise ValueError(f"name: no shipped model {name!r}; shipped: {available_models()}")
    return path


def model_card(name: str) -> dict[str, Any]:
    """The model card of the shipped model ``name`` as a dict."""
    card = model_path(name).with_suffix(".json")
    if not card.is_file():
        raise ValueError(f"name: shipped model {name!r} has no model card ({card.name})")
    result: dict[str, Any] = json.loads(card.read_text())
    return result
