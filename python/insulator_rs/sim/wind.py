"""Wind for the simulated multirotor: a mean wind plus seeded turbulence.

The turbulence follows the low-altitude Dryden model of MIL-F-8785C (as restated in
MIL-HDBK-1797): with ``h`` the height above ground in feet (clamped to 10..1000 ft) and
``W20`` the mean wind at 20 ft,

* sigma_w = 0.1 W20, sigma_u = sigma_v = sigma_w / (0.177 + 0.000823 h)^0.4;
* L_w = h, L_u = L_v = h / (0.177 + 0.000823 h)^1.2 (ft; converted to m here);
* u along the mean wind, v across it (horizontal), w vertical.

Each component is a first-order Gauss-Markov process with the Dryden sigma and correlation
time L / V (V: the airspeed, at least 1 m/s), updated exactly for any step
(phi = exp(-dt V / L)). That is Dryden's longitudinal filter exactly; for the lateral and
vertical components Dryden's filter is second order, and the first-order form keeps their
variance and correlation length but has less power above V / L (a few tenths of a hertz at
a tower). The airframe's drag (a low pass at ~0.25 1/s) filters that band out anyway, and the
first-order form is exact for any step, so the gusts are the same at every integration step
and seeded: one seed, one wind history, on any machine.

Directions: ``from_deg`` is where the wind blows FROM, in degrees clockwise from north, as a
weather report gives it (270: a westerly, blowing toward the east). The mean vector in W
(ENU) is -speed * (sin from, cos from, 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

FT = 0.3048  # m per foot
# MIL-F-8785C's low-altitude model holds below 1000 ft; below 10 ft it is clamped.
DRYDEN_MIN_HEIGHT_FT = 10.0
DRYDEN_MAX_HEIGHT_FT = 1000.0
MIN_AIRSPEED_MPS = 1.0  # the frozen-field correlation time L / V, for a vehicle hovering in calm air


@dataclass(frozen=True)
class WindSpec:
    """A mean wind (``speed`` m/s from ``from_deg`` degrees clockwise from north) and the
    Dryden turbulence scaled by ``turbulence`` (1: MIL-F-8785C's low-altitude intensity for
    that mean wind; 0: a steady wind), seeded by ``seed``."""

    speed: float = 0.0
    from_deg: float = 0.0
    turbulence: float = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("speed", "turbulence"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"wind {name}: must be a finite number >= 0, got {value!r}")
        if not math.isfinite(self.from_deg):
            raise ValueError(f"wind from_deg: must be finite, got {self.from_deg!r}")

    @property
    def mean(self) -> np.ndarray:
        """The mean wind velocity in W (ENU, m/s)."""
        a = math.radians(self.from_deg)
        return -self.speed * np.array([math.sin(a), math.cos(a), 0.0])


def dryden_low_altitude(height_m: float, w20: float) -> tuple[np.ndarray, np.ndarray]:
    """(sigma (3,) m/s, L (3,) m) of the u, v, w components at ``height_m`` above ground for
    a mean wind ``w20`` m/s at 20 ft (MIL-F-8785C low altitude; module docstring)."""
    h = min(max(height_m / FT, DRYDEN_MIN_HEIGHT_FT), DRYDEN_MAX_HEIGHT_FT)
    base = 0.177 + 0.000823 * h
    sigma_w = 0.1 * w20
    sigma_uv = sigma_w / base ** 0.4
    L_uv = h / base ** 1.2 * FT
    return np.array([sigma_uv, sigma_uv, sigma_w]), np.array([L_uv, L_uv, h * FT])


class WindField:
    """The wind the airframe meets, stepped in time (module docstring)."""

    def __init__(self, spec: WindSpec) -> None:
        self.spec = spec
        self.mean = spec.mean
        self._rng = np.random.default_rng(spec.seed)
        speed = spec.speed
        u = self.mean / speed if speed > 0 else np.array([1.0, 0.0, 0.0])
        # columns: u (along the mean wind), v (across it), w (vertical) in W
        self._axes = np.column_stack([u, np.cross([0.0, 0.0, 1.0], u), [0.0, 0.0, 1.0]])
        self._gust = np.zeros(3)  # u, v, w
        self._started = False
        self.velocity = self.mean.copy()

    @property
    def turbulent(self) -> bool:
        return self.spec.speed > 0.0 and self.spec.turbulence > 0.0

    def step(self, dt: float, height_m: float, airspeed: float) -> np.ndarray:
        """Advance the gusts by ``dt`` s at ``height_m`` above ground flying at ``airspeed`` m/s;
        returns the wind velocity in W (m/s)."""
        if not self.turbulent:
            return self.velocity
        sigma, L = dryden_low_altitude(height_m, self.spec.speed)
        sigma = sigma * self.spec.turbulence
        noise = self._rng.standard_normal(3)
        if not self._started:  # start in the stationary distribution
            self._gust = sigma * noise
            self._started = True
        else:
            phi = np.exp(-dt * max(airspeed, MIN_AIRSPEED_MPS) / L)
            self._gust = phi * self._gust + sigma * np.sqrt(1.0 - phi * phi) * noise
        self.velocity = self.mean + self._axes @ self._gust
        return self.velocity
