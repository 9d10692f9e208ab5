"""Shared pytest configuration for the whole suite (keep it small and general)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

# CI runs on two shared cores: per-example deadlines would only measure the neighbours.
settings.register_profile(
    "insulator_rs", deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.load_profile("insulator_rs")


@pytest.fixture
def rng() -> np.random.Generator:
    """A freshly seeded generator, so each test is reproducible on its own."""
    return np.random.default_rng(20251122)
