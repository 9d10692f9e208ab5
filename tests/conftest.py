"""Shared pytest configuration for the whole suite (keep it small and general)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

# CI runs on two shared cores: per-example deadlines would only measure the neighbours.
_COMMON = {"deadline": None, "suppress_health_check": [HealthCheck.too_slow]}
# Exploring (a developer's plain ``pytest``): fresh random examples each run, and the
# example database replays what failed before.
settings.register_profile("dev", **_COMMON)
# The gate (CI, and the README's ``scripts/test.sh``): the same examples on every run and
# every machine, so a red run is the code's doing, not the draw's (one run once failed on a
# case no other run drew). No database: what one machine saw must not change another's run.
settings.register_profile("ci", derandomize=True, database=None, print_blob=True, **_COMMON)
# HYPOTHESIS_PROFILE picks one explicitly; otherwise CI (set by GitHub Actions, GitLab CI and
# most others) means "ci".
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE") or ("ci" if os.environ.get("CI") else "dev"))


@pytest.fixture
def rng() -> np.random.Generator:
    """A freshly seeded generator, so each test is reproducible on its own."""
    return np.random.default_rng(20251122)


@pytest.fixture(scope="session")
def reference_flight(tmp_path_factory: pytest.TempPathFactory):  # noqa: ANN201 (sitl_reference_flight.py)
    """The small scene flown once through PX4 SITL for the whole session, read by three SITL tests
    (``tests/sitl_reference_flight.py``). Here, not imported into each module: a session fixture
    imported into several modules is one fixture per module, and would fly once each."""
    from helpers.sitl_reference_flight import fly_once_for_the_session

    return fly_once_for_the_session(tmp_path_factory)


@pytest.fixture
def px4(tmp_path: Path):  # noqa: ANN201 (a generator fixture)
    """A fresh PX4 SITL (``helpers.px4_sitl.Px4Sitl``), ready for take-off; killed (process group)
    however the test ends. For the SITL modules, which are skipped where the folder is absent
    (``helpers.sitl_suite``)."""
    from helpers.px4_sitl import Px4Sitl
    from helpers.sitl_suite import FOLDER, SPEED

    sitl = Px4Sitl(FOLDER, speed=SPEED, workdir=tmp_path / "px4")
    try:
        yield sitl.start()
    finally:
        sitl.stop()


# optional: without pytest-xdist (the aarch64 stage under qemu, a plain `pytest`) the hook is unknown
@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log):  # noqa: ANN001, ANN201 (xdist's hook)
    """scripts/test.sh runs the suite on pytest-xdist workers (``--dist loadgroup``); this
    scheduler keeps each test module on one worker, so that a module's fixtures (a tower flown
    once for several tests) are built once, and puts tests marked ``xdist_group(name)`` together
    across modules (the PX4 SITL tests that share the session's reference flight). Most tests wait
    on sockets and simulated clocks, not on the CPU: three workers on two cores take the quick
    tier from 4.4 to 1.5 minutes."""
    if config.getoption("dist", None) != "loadgroup":
        return None
    from xdist.scheduler import LoadGroupScheduling

    class ModuleOrGroupScheduling(LoadGroupScheduling):
        def _split_scope(self, nodeid: str) -> str:
            if nodeid.rfind("@") > nodeid.rfind("]"):
                return nodeid.split("@")[-1]
            return nodeid.split("::", 1)[0]

    return ModuleOrGroupScheduling(config, log)
