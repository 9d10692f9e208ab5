"""The one JSON writer of the package: plain values, written atomically.

Every JSON file a run leaves (``summary.json``, ``score.json``, ``fleet_summary.json``) goes
through :func:`write_json`: the file is either the old one or the whole new one, never a
half-written one (temp file + rename, :func:`~insulator_rs.report.folder.write_atomic`).
"""

from __future__ import annotations

import dataclasses
import enum
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from insulator_rs.report.folder import write_atomic


def jsonable(value: Any) -> Any:
    """Plain JSON values: arrays to lists, numpy scalars to Python ones, enums to their values,
    dataclasses to dicts, paths to text, NaN/inf to null."""
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, enum.Enum):
        return jsonable(value.value)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value


def write_json(path: Path, value: Any, *, durable: bool = False) -> Path:
    """``value`` as indented JSON at ``path``, atomically (``durable``: fsync'd as well)."""
    return write_atomic(Path(path), json.dumps(jsonable(value), indent=2, allow_nan=False) + "\n", durable=durable)
