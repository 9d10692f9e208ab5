"""Argument checks shared by the vehicle adapters: finite numbers and 3-vectors.

Each returns the validated value or raises ``ValueError``/``TypeError`` whose message
names the argument (the project's rule for bad input).
"""

from __future__ import annotations

import math

import numpy as np


def as_vector3(value: object, name: str) -> np.ndarray:
    """Validate a 3-vector argument: a (3,) finite float64 copy, or ValueError/TypeError naming it."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be a sequence of 3 numbers, got {type(value).__name__}") from exc
    if array.shape != (3,):
        raise ValueError(f"{name} must have shape (3,), got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite, got {array.tolist()}")
    return array.copy()


def as_finite(value: object, name: str) -> float:
    """Validate a scalar argument: a finite float, or ValueError/TypeError naming it."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise TypeError(f"{name} must be a number, got {type(value).__name__}")
    result = float(value)
    if not math.isfinite(result):
        raise ValueError(f"{name} must be finite, got {result!r}")
    return result


def require_positive(value: object, name: str) -> float:
    """A finite number > 0, or ValueError/TypeError naming ``name``."""
    result = as_finite(value, name)
    if result <= 0.0:
        raise ValueError(f"{name} must be > 0, got {result!r}")
    return result


def require_non_negative(value: object, name: str) -> float:
    """A finite number >= 0, or ValueError/TypeError naming ``name``."""
    result = as_finite(value, name)
    if result < 0.0:
        raise ValueError(f"{name} must be >= 0, got {result!r}")
    return result
