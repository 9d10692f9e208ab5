"""What the PX4 SITL test modules share: PX4's folder, the speed it runs at and the marks that
put a module in the ``sitl`` tier and skip it, saying so, where the folder is absent. A module
sets ``pytestmark = SITL_MARKS``; the fresh-PX4 fixture ``px4`` is in ``conftest.py``."""

from __future__ import annotations

import os

import pytest
from helpers.px4_sitl import sitl_folder

FOLDER = sitl_folder()
SITL_MARKS = [
    pytest.mark.slow,
    pytest.mark.sitl,
    pytest.mark.skipif(FOLDER is None, reason="PX4 SITL folder absent: no ../shared/px4_sitl beside the "
                                              "repository and INSULATOR_RS_PX4_SITL not set"),
]
# PX4 in real time (``-s 1``); ``$INSULATOR_RS_PX4_SPEED`` overrides (test_px4_sitl.py says why
# faster is not the default).
SPEED = float(os.environ.get("INSULATOR_RS_PX4_SPEED", "1"))
