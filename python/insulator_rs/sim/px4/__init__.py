"""A simulated PX4 multirotor on loopback UDP, speaking MAVLink 2 as PX4 does.

Three modules: ``transport`` (the UDP link, signing, link faults), ``autopilot``
(:class:`SimulatedPx4`: commands, setpoints, the thread) and ``telemetry`` (the streams).

It runs in a thread of its own: a UDP socket bound on 127.0.0.1, the PX4-like
autopilot of ``insulator_rs.sim.kinematics.KinematicVehicle`` for the motion
and the rules, and the MAVLink surface of PX4:

* HEARTBEAT with MAV_AUTOPILOT_PX4, MAV_TYPE_QUADROTOR and PX4's custom_mode;
* COMMAND_ACK for arm/disarm, DO_SET_MODE, NAV_TAKEOFF, NAV_LAND,
  NAV_RETURN_TO_LAUNCH, SET_MESSAGE_INTERVAL, REQUEST_MESSAGE with the results
  PX4 v1.16.0 SITL gives (measured against it, see tests/test_px4_sitl.py):
  TEMPORARILY_REJECTED for a refused arming or disarming in the air, ACCEPTED
  for arming an armed vehicle, ACCEPTED for an unknown mode (the HEARTBEAT shows
  it did not switch), TEMPORARILY_REJECTED, when armed, for OFFBOARD without a
  setpoint stream and for POSCTL/MANUAL (no RC) (ACCEPTED without switching
  when disarmed), FAILED for
  SET_MESSAGE_INTERVAL of a message it does not stream, UNSUPPORTED for what it
  does not handle (MAV_CMD_IMAGE_START_CAPTURE included: no camera on the
  autopilot), and no answer at all to gimbal/mount commands;
* SET_POSITION_TARGET_LOCAL_NED with PX4's type_mask semantics (ignored fields
  become NaN = not controlled on that axis; yaw or yaw rate or hold);
* telemetry at configurable rates (SET_MESSAGE_INTERVAL changes them):
  LOCAL_POSITION_NED, ATTITUDE, ATTITUDE_QUATERNION, GLOBAL_POSITION_INT (pymap3d from a geodetic
  origin), HOME_POSITION, EXTENDED_SYS_STATE, SYS_STATUS, BATTERY_STATUS,
  SYSTEM_TIME;
* TIMESYNC as PX4 v1.16 does it (measured on its SITL): a request (``tc1 = 0``) is answered
  with ``tc1`` = the vehicle clock in ns and the request's ``ts1``, and it sends requests of
  its own at 10 Hz;
* MAVLink 2 signing: with a key, anything not correctly signed is dropped
  (RADIO_STATUS excepted, as PX4 does);
* fault injection: packet loss, delay, a lost link, a pilot's mode change, a
  GPS glitch, loss of the position estimate, a command refused or unanswered.

Time: the vehicle's clock (``time_boot_ms``) runs ``time_scale`` times faster
than the wall clock; telemetry rates and PX4's timeouts (COM_OF_LOSS_T...) are
in vehicle time, as in PX4 SITL with a speed factor.

Peers: telemetry goes to ``remote`` if given (as PX4 SITL streams to the
offboard port) and to every address a valid message came from.

The airframe is the in-process multirotor (``sim/kinematics.py``): its attitude (tilted
along the thrust, leaning into the wind) goes out on ATTITUDE and ATTITUDE_QUATERNION.

Limitations (kinematic stand-in): acceleration setpoints are ignored, GLOBAL_POSITION_INT's alt is the WGS84
ellipsoid height of the origin plus the local height.
"""


from __future__ import annotations

import argparse
import math
import os
import time
from typing import Any, NamedTuple

import numpy as np

from insulator_rs.mavlink.client import MavlinkVehicle
from insulator_rs.mavlink.signing import load_signing_key
from insulator_rs.sim.px4.autopilot import UNANSWERED_COMMANDS, SimulatedPx4, setpoint_from_target_local_ned
from insulator_rs.sim.px4.telemetry import DEFAULT_RATES_HZ
from insulator_rs.sim.px4.transport import LOOP_PERIOD_S, MAX_DATAGRAM, MAX_STEP_VEHICLE_S, LinkFaults, SimStats

__all__ = [
    "DEFAULT_RATES_HZ",
    "LOOP_PERIOD_S",
    "MAX_DATAGRAM",
    "MAX_STEP_VEHICLE_S",
    "UNANSWERED_COMMANDS",
    "LinkFaults",
    "SimStats",
    "SimulatedPx4",
    "SimulatedPx4Connection",
    "connect_simulated_px4",
    "main",
    "setpoint_from_target_local_ned",
    "start_simulated_px4",
]


class SimulatedPx4Connection(NamedTuple):
    """A started simulated PX4 and the MAVLink client connected to it. The client owns the
    simulator: ``vehicle.close()`` stops it too."""

    simulator: SimulatedPx4
    vehicle: MavlinkVehicle


def start_simulated_px4(
    *,
    time_scale: float = 1.0,
    signing_key: bytes | str | os.PathLike[str] | None = None,
    sim_options: dict[str, Any] | None = None,
    **client_options: Any,
) -> SimulatedPx4Connection:
    """Start a ``SimulatedPx4`` on a free loopback port and connect the MAVLink client to it
    (``udpout``); return both. The client stops the simulator on ``close()``.
    ``sim_options`` go to ``SimulatedPx4``, ``client_options`` to ``MavlinkVehicle``;
    ``signing_key`` (bytes or a key file) is used by both ends."""
    if signing_key is not None and not isinstance(signing_key, bytes):
        signing_key = load_signing_key(signing_key)
    sim = SimulatedPx4(time_scale=time_scale, signing_key=signing_key, **(sim_options or {})).start()
    try:
        host, port = sim.address
        client = MavlinkVehicle(f"udpout:{host}:{port}", time_scale=time_scale, signing_key=signing_key,
                                **client_options)
    except BaseException:
        sim.stop()
        raise
    client.close_with(sim.stop)
    return SimulatedPx4Connection(sim, client)


def connect_simulated_px4(
    *,
    time_scale: float = 1.0,
    signing_key: bytes | str | os.PathLike[str] | None = None,
    sim_options: dict[str, Any] | None = None,
    **client_options: Any,
) -> MavlinkVehicle:
    """The client of :func:`start_simulated_px4`, for a caller that needs only the vehicle."""
    return start_simulated_px4(time_scale=time_scale, signing_key=signing_key, sim_options=sim_options,
                               **client_options).vehicle


def main(argv: list[str] | None = None) -> int:
    """Run the simulated PX4 standalone: ``python -m insulator_rs.sim.px4``."""
    parser = argparse.ArgumentParser(description="Simulated PX4 multirotor on loopback UDP (MAVLink 2).")
    parser.add_argument("--port", type=int, default=18570, help="UDP port to listen on (default 18570)")
    parser.add_argument("--remote", default="127.0.0.1:14540",
                        help="host:port to stream telemetry to (default 127.0.0.1:14540; '' for none)")
    parser.add_argument("--time-scale", type=float, default=1.0, help="vehicle seconds per wall second")
    parser.add_argument("--signing-key", help="file with the MAVLink 2 signing key (64 hex chars)")
    parser.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: run until Ctrl-C)")
    args = parser.parse_args(argv)
    remote = None
    if args.remote:
        host, _, port = args.remote.rpartition(":")
        remote = (host or "127.0.0.1", int(port))
    key = load_signing_key(args.signing_key) if args.signing_key else None
    sim = SimulatedPx4(port=args.port, remote=remote, time_scale=args.time_scale, signing_key=key)
    with sim:
        print(f"simulated PX4 listening on udp {sim.address[0]}:{sim.address[1]}, streaming to {remote}",
              flush=True)
        deadline = time.monotonic() + args.duration if args.duration > 0 else math.inf
        try:
            while time.monotonic() < deadline:
                time.sleep(0.2)
        except KeyboardInterrupt:
            pass
        state = sim.with_vehicle(lambda v: v.state())
        print(f"stopped: mode {state.mode}, armed {state.armed}, position {np.round(state.position, 2)}, "
              f"stats {sim.stats}")
    return 0

