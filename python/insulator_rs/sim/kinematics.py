"""An in-process kinematic multirotor that behaves like a PX4 vehicle.

Two layers:

* ``MultirotorModel``: the motion. It tracks a ``Setpoint`` (position and/or
  velocity feed-forward and/or yaw or yaw rate) with a proportional position
  loop whose speed is capped so that the vehicle can always stop within its
  acceleration limit, then limits horizontal/vertical velocity and
  acceleration and the yaw rate. The attitude is a multirotor's: the body z axis points
  along the thrust the controller asks for (the acceleration minus gravity, plus the drag it
  fights), limited to PX4's tilt (MPC_TILTMAX_AIR) and followed with a first-order lag;
  the heading is the yaw loop's. Wind (``sim/wind.py``: a mean plus seeded Dryden
  turbulence) acts through a linear drag on the airspeed; the position controller knows
  its own velocity, not the wind, so the wind pushes the vehicle and the velocity loop
  fights it back: in a steady wind it hovers leaning atan(k w / g) into it.
* ``KinematicVehicle``: the autopilot around it, with PX4's flight modes and
  rules (offboard needs a setpoint stream, offboard-loss failsafe after
  ``COM_OF_LOSS_T``, auto-disarm on the ground after ``COM_DISARM_LAND``,
  disarming refused in the air, arming refused without a position estimate or
  with a critical battery), odometry with configurable Gaussian noise, a
  simulation clock, and fault injection (pilot mode change, GPS glitch or loss). It implements
  ``insulator_rs.ports.vehicle.Vehicle``. The simulated PX4 on MAVLink
  (``insulator_rs.sim.px4``) wraps this same class, so the in-process
  path and the MAVLink path fly the same vehicle.

Everything here is in the world frame W (ENU, metres, radians, seconds).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from insulator_rs.exceptions import CommandRejected, VehicleError, VehicleFailsafe
from insulator_rs.validation import as_finite, as_vector3, require_non_negative, require_positive
from insulator_rs.planning.energy import NOMINAL_DRAIN_PER_M, NOMINAL_DRAIN_PER_S
from insulator_rs.poses import interpolate_poses, quaternion_from_rotation, yaw_of
from insulator_rs.ports.vehicle import FlightMode, VehicleState, wrap_angle
from insulator_rs.sim.wind import WindField, WindSpec

# Integration step: the model is sub-stepped so that ``advance`` with a large
# dt stays accurate (the position loop gain times this step is << 1).
MAX_INTEGRATION_STEP_S = 0.01
# Landed when this close to the ground and slower than LANDED_SPEED_MPS.
LANDED_HEIGHT_M = 0.05
LANDED_SPEED_MPS = 0.2
# Takeoff is complete (mode goes to HOLD) within this distance of the target.
TAKEOFF_REACHED_M = 0.3
# Integration steps of true pose kept for the simulated sensors (10 s at 100 Hz): a LiDAR
# frame is cast along the true path of its 0.1 s, which may lie a few seconds back when the
# vehicle runs ahead of a sensor render (the simulated PX4 flies on in wall time).
TRUE_TRACK_SAMPLES = 1000
GRAVITY = 9.80665  # m/s^2
# Linear drag of the airframe on its airspeed (1/s, acceleration per m/s): a 1.5 kg quad of the
# Mid-360 class leans 7 degrees into a 5 m/s wind and 14 degrees into 10 m/s (atan(k w / g)), as
# multirotors of that size do (5-15 degrees at 5-10 m/s).
LINEAR_DRAG_PER_S = 0.25
# The velocity loop's integral holds at most the drag of this wind (m/s).
MAX_HELD_WIND_MPS = 15.0
# The thrust must keep at least this share of gravity upward (a free-fall command is not flown).
MIN_VERTICAL_THRUST = 0.1 * GRAVITY


@dataclass(frozen=True)
class MotionLimits:
    """Kinematic limits of the multirotor (W frame, SI units).

    Defaults cover the paper's planning limits (3 m/s, 12 m/s^2) with margin
    for the position loop. ``position_gain`` (1/s) is the proportional gain
    of the position loop (PX4's MPC_XY_P/MPC_Z_P are about 1).
    """

    max_horizontal_speed: float = 5.0
    max_vertical_speed: float = 3.0
    max_horizontal_acceleration: float = 12.0
    max_vertical_acceleration: float = 6.0
    max_yaw_rate: float = math.radians(90.0)
    position_gain: float = 1.5
    max_tilt: float = math.radians(45.0)  # PX4 MPC_TILTMAX_AIR
    attitude_time_constant: float = 0.15  # s: the attitude loop's first-order lag
    # The velocity loop, PI as PX4's (MPC_XY_VEL_P_ACC / _I_ACC): the proportional part a
    # first-order response of this time constant (s), the integral part (1/s^2) what takes a
    # steady push (the wind the loop does not know) off. Dead-beat before (the whole step of
    # each 50 ms setpoint in the first 10 ms substep), the commanded thrust was a train of
    # pulses and the attitude saw-toothed 2-3 degrees between the 20 Hz poses a flight records:
    # LiDAR points deskewed with those poses sat 0.2-0.6 m off in hard manoeuvres and
    # `calibrate time-offset` read an 80 ms camera lateness as 60 ms. A real airframe's
    # acceleration, and so its tilt, is continuous. 0.1 s and 10 /s^2: critically damped and
    # over (zeta 1.6), a wind gust taken off within about a second.
    velocity_time_constant: float = 0.1
    velocity_integral_gain: float = 10.0
    drag: float = LINEAR_DRAG_PER_S  # 1/s

    def __post_init__(self) -> None:
        for name in ("max_horizontal_speed", "max_vertical_speed", "max_horizontal_acceleration",
                     "max_vertical_acceleration", "max_yaw_rate", "position_gain", "attitude_time_constant",
                     "velocity_time_constant"):
            require_positive(getattr(self, name), name)
        for name in ("drag", "velocity_integral_gain"):
            require_non_negative(getattr(self, name), name)
        if not 0.0 < self.max_tilt < math.pi / 2:
            raise ValueError(f"max_tilt must be in (0, pi/2) rad, got {self.max_tilt!r}")


@dataclass(frozen=True)
class OdometryNoise:
    """Standard deviations of the Gaussian noise on published odometry.

    ``position`` in m, ``velocity`` in m/s, ``yaw`` in rad, per axis.
    """

    position: float = 0.0
    velocity: float = 0.0
    yaw: float = 0.0

    def __post_init__(self) -> None:
        for name in ("position", "velocity", "yaw"):
            require_non_negative(getattr(self, name), f"noise {name}")


@dataclass(frozen=True)
class AutopilotParameters:
    """PX4 parameters the vehicle honours (PX4 names in brackets, PX4 defaults).

    offboard_loss_timeout [COM_OF_LOSS_T] s; offboard_loss_mode [COM_OBL_RC_ACT]
    the mode PX4 falls back to when the offboard stream stops (PX4's default 0,
    "Position mode": the SITL's HEARTBEAT then shows POSCTL); disarm_land_delay [COM_DISARM_LAND]
    s; preflight_disarm_delay [COM_DISARM_PRFLT] s; takeoff_speed [MPC_TKO_SPEED]
    m/s; land_speed [MPC_LAND_SPEED] m/s; return_altitude [RTL_RETURN_ALT] m
    above home; takeoff_altitude [MIS_TAKEOFF_ALT] m above home, when a takeoff
    names none; battery_critical [BAT_CRIT_THR] fraction (below it: RTL, and
    arming is refused).

    The pack (``KinematicVehicle.battery_fraction``) drains while armed with time and with
    distance, as a multirotor's does: ``battery_drain_per_s`` [1 / SIM_BAT_DRAIN] the hover
    power (1/1500: a 25 minute hover endurance, the class of a 1.5 kg quadrotor carrying a
    Mid-360 and a gimbal on a 4S 5 Ah pack) and ``battery_drain_per_m`` per metre flown (5e-5:
    13 J of a 266 kJ pack per metre, the climbs, accelerations and drag of the passes above the
    hover power; a 1 m/s pass costs 7 % more than hovering). ``battery_floor``
    [SIM_BAT_MIN_PCT]: the charge never drains below it; 0 here, the whole pack (PX4 SIH's
    default of 50 % keeps SITL missions clear of battery failsafes, and would hide the reserve).
    """

    offboard_loss_timeout: float = 1.0
    offboard_loss_mode: str = "POSCTL"
    disarm_land_delay: float = 2.0
    preflight_disarm_delay: float = 10.0
    takeoff_speed: float = 1.5
    land_speed: float = 0.7
    return_altitude: float = 60.0
    takeoff_altitude: float = 2.5
    battery_critical: float = 0.07
    battery_drain_per_s: float = NOMINAL_DRAIN_PER_S
    battery_drain_per_m: float = NOMINAL_DRAIN_PER_M
    battery_floor: float = 0.0

    def __post_init__(self) -> None:
        for name in ("offboard_loss_timeout", "takeoff_speed", "land_speed", "takeoff_altitude"):
            require_positive(getattr(self, name), name)
        for name in ("disarm_land_delay", "preflight_disarm_delay", "return_altitude", "battery_drain_per_s",
                     "battery_drain_per_m"):
            require_non_negative(getattr(self, name), name)
        if self.offboard_loss_mode not in ("POSCTL", "HOLD", "LAND", "RTL"):
            raise ValueError(f"offboard_loss_mode must be POSCTL, HOLD, LAND or RTL, got {self.offboard_loss_mode!r}")
        if not 0.0 <= self.battery_floor <= 1.0:
            raise ValueError(f"battery_floor must be in [0, 1], got {self.battery_floor!r}")
        if not 0.0 <= self.battery_critical < 1.0:
            raise ValueError(f"battery_critical must be in [0, 1), got {self.battery_critical!r}")


@dataclass(frozen=True)
class Setpoint:
    """What the position controller tracks (W frame).

    Any field may be None (and position/velocity components NaN, per axis): no
    position means velocity control; no velocity means
    zero feed-forward (or, with no position either, stop); ``yaw`` (rad, from
    east, counter-clockwise) takes precedence over ``yaw_rate`` (rad/s); with
    neither, the heading is held.
    """

    position: np.ndarray | None = None
    velocity: np.ndarray | None = None
    yaw: float | None = None
    yaw_rate: float | None = None
    max_speed: float | None = None  # m/s, tighter cap than the limits (takeoff speed)


def _clamp_norm(vector: np.ndarray, limit: float) -> np.ndarray:
    norm = float(np.linalg.norm(vector))
    if norm > limit:
        return vector * (limit / norm)
    return vector


def _position_correction(error: np.ndarray, gain: float, max_acceleration: float) -> np.ndarray:
    """Velocity that closes ``error``: gain * error, capped at sqrt(2 a |e|) so the
    vehicle can still stop at the target with acceleration ``max_acceleration``."""
    distance = float(np.linalg.norm(error))
    if distance == 0.0:
        return np.zeros_like(error)
    speed = min(gain * distance, math.sqrt(2.0 * max_acceleration * distance))
    return error * (speed / distance)


def attitude_from_thrust(thrust_direction: np.ndarray, yaw: float) -> np.ndarray:
    """R_w_b (3x3) whose z axis is ``thrust_direction`` (unit, W) and whose Z-Y-X yaw is ``yaw``
    (the yaw loop's heading is kept exactly; roll and pitch tilt the thrust)."""
    c, s = math.cos(yaw), math.sin(yaw)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    z = Rz.T @ thrust_direction  # the thrust in the heading frame
    roll = -math.asin(max(-1.0, min(1.0, float(z[1]))))
    pitch = math.atan2(float(z[0]), float(z[2]))
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return Rz @ Ry @ Rx


def limit_tilt(thrust: np.ndarray, max_tilt: float) -> np.ndarray:
    """The specific thrust (W, m/s^2) with its vertical part kept at least MIN_VERTICAL_THRUST
    and its horizontal part cut so that it tilts at most ``max_tilt`` rad from vertical (PX4's
    position controller keeps the vertical thrust and limits the tilt)."""
    out = np.array(thrust, dtype=np.float64)
    out[2] = max(out[2], MIN_VERTICAL_THRUST)
    horizontal = float(np.hypot(out[0], out[1]))
    limit = out[2] * math.tan(max_tilt)
    if horizontal > limit:
        out[:2] *= limit / horizontal
    return out


@dataclass
class MultirotorModel:
    """True state of the multirotor (W frame): position, velocity, heading, attitude R_w_b and
    body rates; its tracking law; the wind it flies in (None: still air)."""

    limits: MotionLimits = field(default_factory=MotionLimits)
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    yaw: float = 0.0
    ground_z: float = 0.0
    wind: WindField | None = None
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    angular_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    thrust_direction: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    wind_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    # the velocity loop's integral (m/s^2, W): the push it has learnt to hold against
    velocity_integral: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        self.rotation = attitude_from_thrust(self.thrust_direction, self.yaw)

    def desired_velocity(self, setpoint: Setpoint) -> np.ndarray:
        """Velocity command for ``setpoint`` before the acceleration limit (m/s, W)."""
        lim = self.limits
        # A NaN component means "not controlled on this axis" (PX4's convention for
        # ignored type_mask fields): no feed-forward, no position correction.
        desired = np.zeros(3) if setpoint.velocity is None \
            else np.nan_to_num(np.asarray(setpoint.velocity, dtype=float), nan=0.0)
        if setpoint.position is not None:
            error = np.nan_to_num(np.asarray(setpoint.position, dtype=float) - self.position, nan=0.0)
            desired[:2] += _position_correction(error[:2], lim.position_gain, lim.max_horizontal_acceleration)
            desired[2:] += _position_correction(error[2:], lim.position_gain, lim.max_vertical_acceleration)
        desired[:2] = _clamp_norm(desired[:2], lim.max_horizontal_speed)
        desired[2] = float(np.clip(desired[2], -lim.max_vertical_speed, lim.max_vertical_speed))
        if setpoint.max_speed is not None:
            desired = _clamp_norm(desired, setpoint.max_speed)
        return desired

    def step(self, dt: float, setpoint: Setpoint | None) -> None:
        """Advance the true state by ``dt`` seconds toward ``setpoint``.

        ``None`` means motors off: the vehicle stays where it is on the ground (it
        is only ever disarmed on the ground).
        """
        remaining = dt
        while remaining > 1e-12:
            h = min(MAX_INTEGRATION_STEP_S, remaining)
            remaining -= h
            wind = self._wind_step(h)
            if setpoint is None:
                self.velocity = np.zeros(3)
                self.velocity_integral = np.zeros(3)
                self._attitude_step(h, np.array([0.0, 0.0, 1.0]))
                continue
            self._substep(h, setpoint, wind)

    def _wind_step(self, h: float) -> np.ndarray:
        if self.wind is None:
            return self.wind_velocity
        airspeed = float(np.linalg.norm(self.velocity - self.wind.mean))
        self.wind_velocity = self.wind.step(h, float(self.position[2] - self.ground_z), airspeed)
        return self.wind_velocity

    def _substep(self, h: float, setpoint: Setpoint, wind: np.ndarray) -> None:
        lim = self.limits
        velocity_error = self.desired_velocity(setpoint) - self.velocity
        wanted = velocity_error * (1.0 - math.exp(-h / lim.velocity_time_constant)) + self.velocity_integral * h
        change = wanted.copy()
        change[:2] = _clamp_norm(change[:2], lim.max_horizontal_acceleration * h)
        change[2] = float(np.clip(change[2], -lim.max_vertical_acceleration * h,
                                  lim.max_vertical_acceleration * h))
        # never commanded past the speed limits (the integral alone could carry it over)
        commanded = self.velocity + change
        commanded[:2] = _clamp_norm(commanded[:2], max(lim.max_horizontal_speed, float(np.linalg.norm(self.velocity[:2]))))
        commanded[2] = float(np.clip(commanded[2], -max(lim.max_vertical_speed, abs(self.velocity[2])),
                                     max(lim.max_vertical_speed, abs(self.velocity[2]))))
        change = commanded - self.velocity
        # The thrust the controller asks for: the acceleration it wants, gravity, and the drag
        # of its own velocity (it knows its velocity, not the wind); tilt-limited as PX4's.
        drag_known = lim.drag * self.velocity
        requested = change / h + drag_known + np.array([0.0, 0.0, GRAVITY])
        thrust = limit_tilt(requested, lim.max_tilt)
        flown_as_asked = bool(np.allclose(change, wanted, rtol=0.0, atol=1e-12)
                              and np.allclose(thrust, requested, rtol=0.0, atol=1e-9))
        airborne = bool(self.position[2] > self.ground_z + 1e-6)
        drag = lim.drag * (self.velocity - wind) if airborne else drag_known
        acceleration = thrust - np.array([0.0, 0.0, GRAVITY]) - drag
        new_velocity = self.velocity + acceleration * h
        self.position = self.position + 0.5 * (self.velocity + new_velocity) * h
        self.velocity = new_velocity
        grounded = False
        if self.position[2] <= self.ground_z and self.velocity[2] <= 0.0:
            # Ground contact: no sinking, no sliding.
            self.position[2] = self.ground_z
            self.velocity = np.zeros(3)
            self.velocity_integral = np.zeros(3)
            grounded = True
        elif flown_as_asked:
            # integrate only while the command is flown as asked (not cut by the acceleration
            # or tilt limit: no wind-up), and at most the push of a 15 m/s wind's drag
            self.velocity_integral = _clamp_norm(
                self.velocity_integral + lim.velocity_integral_gain * velocity_error * h,
                lim.drag * MAX_HELD_WIND_MPS)
        max_turn = lim.max_yaw_rate * h
        if setpoint.yaw is not None:
            error = wrap_angle(setpoint.yaw - self.yaw)
            self.yaw = wrap_angle(self.yaw + float(np.clip(error, -max_turn, max_turn)))
        elif setpoint.yaw_rate is not None:
            self.yaw = wrap_angle(self.yaw + float(np.clip(setpoint.yaw_rate * h, -max_turn, max_turn)))
        self._attitude_step(h, np.array([0.0, 0.0, 1.0]) if grounded else thrust / np.linalg.norm(thrust))

    def _attitude_step(self, h: float, thrust_direction: np.ndarray) -> None:
        """The body z axis follows ``thrust_direction`` with the attitude loop's first-order lag;
        the heading is the yaw loop's. Updates R_w_b and the body rates."""
        alpha = 1.0 - math.exp(-h / self.limits.attitude_time_constant)
        z = self.thrust_direction + alpha * (thrust_direction - self.thrust_direction)
        self.thrust_direction = z / np.linalg.norm(z)
        previous = self.rotation
        self.rotation = attitude_from_thrust(self.thrust_direction, self.yaw)
        d = previous.T @ self.rotation  # ~ I + [w h]x for a small step
        self.angular_velocity = np.array([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]]) / (2.0 * h)

    def on_ground(self) -> bool:
        """Landed: within LANDED_HEIGHT_M of the ground and slower than LANDED_SPEED_MPS."""
        return bool(self.position[2] - self.ground_z <= LANDED_HEIGHT_M
                    and np.linalg.norm(self.velocity) < LANDED_SPEED_MPS)


class SimClock:
    """Simulated time in seconds; shared by the vehicle and the simulated sensors."""

    def __init__(self, start: float = 0.0) -> None:
        self.now = as_finite(start, "start")

    def advance(self, dt: float) -> float:
        """Move time forward by ``dt`` s and return the new time."""
        self.now += dt
        return self.now


class KinematicVehicle:
    """A PX4-like multirotor simulated in process; implements ``Vehicle``.

    Flight sequence as with PX4: stream ``send_setpoint`` (offboard needs the
    stream), ``arm``, ``start_offboard`` (or ``takeoff`` first: AUTO_TAKEOFF
    climbs during ``advance`` calls and switches to HOLD on arrival), keep
    streaming setpoints every tick while calling ``advance(dt)``, then ``land``.
    If setpoints stop for ``params.offboard_loss_timeout`` of simulated time in
    OFFBOARD, the vehicle falls back to ``offboard_loss_mode`` (COM_OBL_RC_ACT) and
    ``state().fault`` says why; as PX4 v1.16 does, the fallback clears when setpoints come
    again before any other mode is chosen: OFFBOARD resumes and the fault clears.
    As in PX4 v1.14+, offboard may be engaged on the ground, before arming, as
    long as the setpoint stream is running.
    """

    def __init__(
        self,
        *,
        start_position: object = (0.0, 0.0, 0.0),
        start_yaw: float = 0.0,
        limits: MotionLimits | None = None,
        params: AutopilotParameters | None = None,
        noise: OdometryNoise | None = None,
        seed: int | None = 0,
        clock: SimClock | None = None,
        wind: WindSpec | None = None,
        ground_z: float | None = None,
    ) -> None:
        position = as_vector3(start_position, "start_position")
        self.model = MultirotorModel(
            limits=limits or MotionLimits(),
            position=position,
            yaw=wrap_angle(as_finite(start_yaw, "start_yaw")),
            ground_z=float(position[2]) if ground_z is None else as_finite(ground_z, "ground_z"),
            wind=None if wind is None or wind.speed == 0.0 else WindField(wind),
        )
        self.wind = wind or WindSpec()
        self.params = params or AutopilotParameters()
        self.noise = noise or OdometryNoise()
        self.clock = clock or SimClock()
        self.home = position.copy()
        self.armed = False
        self.mode = FlightMode.HOLD
        # the pack's charge (see AutopilotParameters); None: no battery monitor (PX4's -1)
        self.battery_fraction: float | None = 1.0
        self.fault: str | None = None
        self.position_valid = True
        self._rng = np.random.default_rng(seed)
        self._gps_offset = np.zeros(3)
        self._setpoint: Setpoint | None = None
        self._last_setpoint_time = -math.inf
        self._hold_position = position.copy()
        self._hold_yaw = self.model.yaw
        self._takeoff_target: np.ndarray | None = None
        self._rtl_phase = ""
        self._landed_since: float | None = self.clock.now
        self._armed_since = -math.inf
        self._has_taken_off = False
        self._closed = False
        self._pending_failsafe: VehicleFailsafe | None = None
        # the offboard-loss fallback is active and may clear (PX4 v1.16: when setpoints come again)
        self._offboard_fallback = False
        # (time, true T_w_b) after each integration step, for the simulated sensors
        self.true_track: deque[tuple[float, np.ndarray]] = deque(maxlen=TRUE_TRACK_SAMPLES)
        self.true_track.append((self.clock.now, self.true_T_w_b()))

    # -- Vehicle protocol ------------------------------------------------------

    def state(self) -> VehicleState:
        """Odometry as published: true state plus noise (and any GPS glitch offset)."""
        self._check_open()
        model = self.model
        position = model.position + self._gps_offset
        velocity = model.velocity.copy()
        R = model.rotation
        if self.noise.position > 0.0:
            position = position + self._rng.normal(0.0, self.noise.position, 3)
        if self.noise.velocity > 0.0:
            velocity = velocity + self._rng.normal(0.0, self.noise.velocity, 3)
        if self.noise.yaw > 0.0:  # a heading error: the estimate turned about W's vertical
            e = float(self._rng.normal(0.0, self.noise.yaw))
            R = np.array([[math.cos(e), -math.sin(e), 0.0], [math.sin(e), math.cos(e), 0.0], [0.0, 0.0, 1.0]]) @ R
        yaw = yaw_of(R)
        return VehicleState(
            time=self.clock.now,
            position=position,
            velocity=velocity,
            yaw=yaw,
            armed=self.armed,
            mode=self.mode.value,
            landed=self.landed,
            battery_fraction=self.battery_fraction,
            healthy=self.fault is None and self.position_valid,
            fault=self.fault,
            attitude=quaternion_from_rotation(R),
            angular_velocity=model.angular_velocity.copy(),
        )

    def arm(self) -> None:
        """Arm the motors; a no-op when already armed (PX4 answers ACCEPTED)."""
        self._check_open()
        if self.armed:
            return
        if not self.position_valid:
            raise CommandRejected("arm", "no valid position estimate")
        if self.battery_fraction is not None and self.battery_fraction <= self.params.battery_critical:
            raise CommandRejected("arm", f"battery critical ({self.battery_fraction:.0%})")
        if self.mode == FlightMode.OFFBOARD and not self._setpoints_fresh():
            raise CommandRejected("arm", "offboard mode without a setpoint stream")
        self.armed = True
        self._armed_since = self.clock.now
        self._has_taken_off = False
        self.home = self.model.position.copy()
        if self.mode == FlightMode.HOLD:
            self._enter_hold_here()

    def disarm(self, *, force: bool = False) -> None:
        """Disarm; refused in the air as PX4 does unless ``force`` (PX4's 21196)."""
        self._check_open()
        if not self.armed:
            return
        if not self.landed and not force:
            raise CommandRejected("disarm", "not landed")
        self._disarm()

    def set_mode(self, mode: FlightMode | str) -> None:
        """Switch flight mode as MAV_CMD_DO_SET_MODE does (PX4's mode requirements)."""
        self._check_open()
        try:
            target = FlightMode(mode)
        except ValueError as exc:
            raise ValueError(f"mode must be one of {[m.value for m in FlightMode]}, got {mode!r}") from exc
        if target == self.mode:
            return
        if target == FlightMode.OFFBOARD:
            if not self._setpoints_fresh():
                raise CommandRejected("set mode OFFBOARD", "no offboard setpoint stream")
            if not self.position_valid:
                raise CommandRejected("set mode OFFBOARD", "no valid position estimate")
        elif target in (FlightMode.POSCTL, FlightMode.HOLD, FlightMode.TAKEOFF,
                        FlightMode.RTL, FlightMode.MISSION) and not self.position_valid:
            raise CommandRejected(f"set mode {target.value}", "no valid position estimate")
        if target == FlightMode.TAKEOFF:
            self.request_takeoff(self.params.takeoff_altitude)
            return
        self._offboard_fallback = False  # a mode chosen: PX4's intended mode is no longer OFFBOARD
        self._switch(target)

    def start_offboard(self) -> None:
        """Switch to OFFBOARD; refused unless setpoints arrived within COM_OF_LOSS_T."""
        self.set_mode(FlightMode.OFFBOARD)

    def takeoff(self, altitude: float) -> None:
        """Start AUTO_TAKEOFF to ``altitude`` m above home; the climb happens in ``advance``.

        Refused while disarmed (the mission must arm first).
        """
        self._check_open()
        altitude = require_positive(altitude, "altitude")
        if not self.armed:
            raise CommandRejected("takeoff", "vehicle is disarmed")
        self.request_takeoff(altitude)

    def request_takeoff(self, altitude: float) -> None:
        """Enter AUTO_TAKEOFF to ``altitude`` m above home, as PX4's NAV_TAKEOFF does:
        accepted while disarmed too (the climb starts once armed)."""
        self._check_open()
        altitude = require_positive(altitude, "altitude")
        if not self.position_valid:
            raise CommandRejected("takeoff", "no valid position estimate")
        self._begin_takeoff(altitude)

    def send_setpoint(
        self, position: np.ndarray, velocity: np.ndarray | None = None, yaw: float | None = None
    ) -> None:
        """Stream a position (+ velocity feed-forward, + yaw) setpoint in W."""
        self.command_setpoint(Setpoint(
            position=as_vector3(position, "position"),
            velocity=None if velocity is None else as_vector3(velocity, "velocity"),
            yaw=None if yaw is None else as_finite(yaw, "yaw"),
        ))

    def command_setpoint(self, setpoint: Setpoint) -> None:
        """Accept any offboard setpoint (used by the MAVLink sim for every type_mask)."""
        self._check_open()
        self._setpoint = setpoint
        self._last_setpoint_time = self.clock.now

    def advance(self, dt: float) -> VehicleState:
        """Let ``dt`` seconds of simulated time pass, run the autopilot, return ``state()``.

        Raises ``VehicleFailsafe`` (after the whole ``dt`` has been simulated) when a
        failsafe fired: offboard setpoints lost, battery critical, position lost.
        """
        self._check_open()
        dt = require_positive(dt, "dt")
        remaining = dt
        while remaining > 1e-12:
            h = min(MAX_INTEGRATION_STEP_S, remaining)
            remaining -= h
            self._autopilot_step(h)
            self.true_track.append((self.clock.now, self.true_T_w_b()))
        self.raise_pending_failsafe()
        return self.state()

    def true_T_w_b(self) -> np.ndarray:
        """The airframe's true pose now (4x4: full attitude, no odometry noise, no GPS glitch)."""
        T = np.eye(4)
        T[:3, :3] = self.model.rotation
        T[:3, 3] = self.model.position
        return T

    def true_pose_at(self, time: float) -> np.ndarray:
        """The true T_w_b (4x4, full attitude) at ``time`` (s), interpolated over the last
        integration steps (clamped to the oldest/newest kept): where simulated sensors were at
        that instant."""
        times = np.fromiter((s[0] for s in self.true_track), float, len(self.true_track))
        k = int(np.searchsorted(times, time))
        if k <= 0 or k >= len(times):
            return self.true_track[0 if k <= 0 else -1][1].copy()
        (t0, T0), (t1, T1) = self.true_track[k - 1], self.true_track[k]
        if not t1 > t0:
            return T1.copy()
        # poses.py interpolates (linear in position, geodesic in rotation)
        return interpolate_poses(np.array([t0, t1]), np.stack([T0, T1]), np.array([time]))[0]

    def raise_pending_failsafe(self) -> None:
        """Raise the failsafe that fired since the last call, if any (once each)."""
        pending, self._pending_failsafe = self._pending_failsafe, None
        if pending is not None:
            raise pending

    def land(self) -> None:
        """Switch to AUTO_LAND at the current position (always accepted, as in PX4)."""
        self._check_open()
        self._offboard_fallback = False
        self._switch(FlightMode.LAND)

    def hold(self) -> None:
        """Switch to AUTO_LOITER where the vehicle is (refused without a position estimate, as in PX4)."""
        self.set_mode(FlightMode.HOLD)

    def return_to_launch(self) -> None:
        """Switch to AUTO_RTL: climb to RTL altitude, fly home, land."""
        self.set_mode(FlightMode.RTL)

    def close(self) -> None:
        """Release the vehicle; later calls raise VehicleError."""
        self._closed = True

    def set_wind(self, wind: WindSpec) -> None:
        """Fly in ``wind`` from now on (a mean plus seeded Dryden turbulence; speed 0: still air)."""
        self.wind = wind
        self.model.wind = None if wind.speed == 0.0 else WindField(wind)
        if self.model.wind is None:
            self.model.wind_velocity = np.zeros(3)

    # -- fault injection -------------------------------------------------------

    def inject_gps_glitch(self, offset: object) -> None:
        """Offset the published position by ``offset`` (m, W) until cleared with zeros."""
        self._gps_offset = as_vector3(offset, "offset")

    def inject_position_loss(self, lost: bool = True) -> None:
        """Lose (or regain) the position estimate: the vehicle holds in place (PX4
        would descend) and refuses arming and position modes while lost."""
        self.position_valid = not lost
        if lost and self.armed and self.mode != FlightMode.LAND:
            self._failsafe(FlightMode.LAND, "position estimate lost")

    def autopilot_failsafe(self, mode: FlightMode, reason: str) -> None:
        """An autopilot failsafe decided outside the airframe (the simulated PX4's data-link
        loss) switches to ``mode``; ``state().fault`` says ``reason``."""
        self._check_open()
        self._failsafe(mode, reason)

    def clear_failsafe(self, mode: FlightMode) -> None:
        """A failsafe that clears with its condition (PX4's Hold action): the fault clears and
        the vehicle goes back to ``mode``, the take-off climb included (its target kept)."""
        self._check_open()
        self.fault = None
        if mode == FlightMode.TAKEOFF and self._takeoff_target is not None:
            self.mode = FlightMode.TAKEOFF
        elif mode != FlightMode.TAKEOFF:
            self.set_mode(mode)

    # -- internals ---------------------------------------------------------------

    @property
    def landed(self) -> bool:
        return self.model.on_ground()

    def _check_open(self) -> None:
        if self._closed:
            raise VehicleError("vehicle is closed")

    def _setpoints_fresh(self) -> bool:
        return self.clock.now - self._last_setpoint_time <= self.params.offboard_loss_timeout

    def _switch(self, mode: FlightMode) -> None:
        self.mode = mode
        if mode in (FlightMode.HOLD, FlightMode.POSCTL, FlightMode.MISSION):
            self._enter_hold_here()
        elif mode == FlightMode.RTL:
            self._rtl_phase = "climb"

    def _enter_hold_here(self) -> None:
        self._hold_position = self.model.position.copy()
        self._hold_yaw = self.model.yaw

    def _begin_takeoff(self, altitude: float) -> None:
        self._offboard_fallback = False
        self._takeoff_target = np.array([self.model.position[0], self.model.position[1],
                                         self.home[2] + altitude])
        self.mode = FlightMode.TAKEOFF

    def _disarm(self) -> None:
        self._offboard_fallback = False
        self.armed = False
        self._takeoff_target = None
        self.mode = FlightMode.HOLD
        self._enter_hold_here()

    def _failsafe(self, mode: FlightMode, reason: str) -> None:
        self._offboard_fallback = False  # another failsafe ends the offboard fallback's claim
        self.fault = reason
        self._switch(mode)
        self._pending_failsafe = VehicleFailsafe(reason, mode.value.lower())

    def _active_setpoint(self) -> Setpoint:
        """The setpoint the position controller tracks in the current mode."""
        mode = self.mode
        if mode == FlightMode.OFFBOARD and self._setpoint is not None:
            return self._setpoint
        if mode == FlightMode.TAKEOFF and self._takeoff_target is not None:
            return Setpoint(position=self._takeoff_target, yaw=self._hold_yaw,
                            max_speed=self.params.takeoff_speed)
        if mode == FlightMode.LAND:
            return Setpoint(velocity=np.array([0.0, 0.0, -self.params.land_speed]))
        if mode == FlightMode.RTL:
            return self._rtl_setpoint()
        if not self.position_valid:
            return Setpoint(velocity=np.zeros(3))
        return Setpoint(position=self._hold_position, yaw=self._hold_yaw)

    def _rtl_setpoint(self) -> Setpoint:
        pos = self.model.position
        cruise_z = max(pos[2], self.home[2] + self.params.return_altitude)
        if self._rtl_phase == "climb":
            if pos[2] >= self.home[2] + self.params.return_altitude - TAKEOFF_REACHED_M:
                self._rtl_phase = "return"
            else:
                return Setpoint(position=np.array([pos[0], pos[1], cruise_z]))
        above_home = np.array([self.home[0], self.home[1], cruise_z])
        if self._rtl_phase == "return":
            if np.linalg.norm(above_home[:2] - pos[:2]) < TAKEOFF_REACHED_M:
                self._rtl_phase = "land"
            else:
                return Setpoint(position=above_home)
        return Setpoint(position=np.array([self.home[0], self.home[1], pos[2]]),
                        velocity=np.array([0.0, 0.0, -self.params.land_speed]))

    def _autopilot_step(self, h: float) -> None:
        p = self.params
        now = self.clock.advance(h)
        if self.armed:
            if self.battery_fraction is not None and self.battery_fraction > p.battery_floor:
                used = (p.battery_drain_per_s + p.battery_drain_per_m * float(np.linalg.norm(self.model.velocity))) * h
                self.battery_fraction = max(p.battery_floor, self.battery_fraction - used)
            if (self.battery_fraction is not None and self.battery_fraction <= p.battery_critical and not self.landed
                    and self.mode not in (FlightMode.RTL, FlightMode.LAND)):
                self._failsafe(FlightMode.RTL, f"battery critical ({self.battery_fraction:.0%})")
            if self.mode == FlightMode.OFFBOARD and not self._setpoints_fresh():
                self._failsafe(FlightMode(p.offboard_loss_mode),
                               f"offboard setpoints lost for more than {p.offboard_loss_timeout:g} s")
                self._offboard_fallback = True
            elif self._offboard_fallback and self._setpoints_fresh():
                # PX4 v1.16's offboard loss is a mode fallback that clears with its condition:
                # setpoints again, and nobody chose another mode since, so the intended OFFBOARD
                # resumes and the failsafe flag clears (SITL, session 17: RTL at 32.000 s,
                # OFFBOARD again at 32.060 s after a 1.19 s stall of the companion)
                self._offboard_fallback = False
                self.fault = None
                self._switch(FlightMode.OFFBOARD)
        self.model.step(h, self._active_setpoint() if self.armed else None)
        if self.armed and self.mode == FlightMode.TAKEOFF and self._takeoff_target is not None \
                and np.linalg.norm(self._takeoff_target - self.model.position) < TAKEOFF_REACHED_M:
            # PX4 loiters at the takeoff point, not where the climb was declared done.
            target, self._takeoff_target = self._takeoff_target, None
            self._switch(FlightMode.HOLD)
            self._hold_position = target
        landed = self.landed
        if not landed and self.armed:
            self._has_taken_off = True
            self._landed_since = None
        elif self._landed_since is None:
            self._landed_since = now
        if self.armed and landed:
            # PX4: COM_DISARM_LAND after a landing, COM_DISARM_PRFLT when no
            # takeoff followed arming; a value of 0 disables the check.
            if self._has_taken_off:
                since = now if self._landed_since is None else self._landed_since
                delay = p.disarm_land_delay
            else:
                since, delay = self._armed_since, p.preflight_disarm_delay
            if delay > 0.0 and now - since >= delay:
                self._disarm()
