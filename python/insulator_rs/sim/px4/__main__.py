"""``python -m insulator_rs.sim.px4``: the simulated PX4 standalone."""

import sys

from insulator_rs.sim.px4 import main

sys.exit(main())
