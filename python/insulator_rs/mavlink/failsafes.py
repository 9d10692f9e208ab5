"""Client-side failsafes: what the companion computer notices on its own.

* the autopilot's heartbeat lost (``link_loss_timeout``): setpoints stop; the
  autopilot flies its own failsafe (offboard loss, COM_OF_LOSS_T);
* a mode change out of OFFBOARD that we did not command (the pilot, or PX4's own
  failsafe, took the vehicle): setpoint streaming stops at once, in the receiving
  thread;
* local position stale while the link is alive: HOLD;
* battery low: RTL or HOLD.

The monitor decides (in the receiving thread, under the client's lock); the
action that needs commands (hold, return) runs in the mission's thread when it
next calls ``advance``, which raises ``VehicleFailsafe`` once per reason.
"""

from __future__ import annotations

from dataclasses import dataclass

from insulator_rs.mavlink.telemetry import TelemetryStore
from insulator_rs.validation import require_positive
from insulator_rs.ports.vehicle import FlightMode


@dataclass(frozen=True)
class FailsafeSettings:
    """Client-side failsafe thresholds (wall seconds; battery as a fraction)."""

    link_loss_timeout: float = 3.0
    position_stale_timeout: float = 1.0
    low_battery_fraction: float = 0.2
    low_battery_action: str = "return"  # "return" (RTL) or "hold"

    def __post_init__(self) -> None:
        for name in ("link_loss_timeout", "position_stale_timeout"):
            require_positive(getattr(self, name), name)
        if not 0.0 <= self.low_battery_fraction < 1.0:
            raise ValueError(f"low_battery_fraction must be in [0, 1), got {self.low_battery_fraction!r}")
        if self.low_battery_action not in ("return", "hold"):
            raise ValueError(f"low_battery_action must be 'return' or 'hold', got {self.low_battery_action!r}")


class FailsafeMonitor:
    """Turns telemetry into at most one pending failsafe per reason (see the module docstring).

    ``commanding_stopped`` is set when the vehicle was taken from us: nothing more may
    be streamed. ``fault`` keeps the last reason for ``VehicleState.fault``.
    """

    def __init__(self, settings: FailsafeSettings) -> None:
        self.settings = settings
        self.fault: str | None = None
        self.pending: tuple[str, str] | None = None
        self.commanding_stopped: str | None = None
        self.expected_mode: str | None = None  # the mode we last commanded
        self.offboard_engaged = False
        self._raised: set[str] = set()

    def raise_failsafe(self, reason: str, action: str) -> None:
        if reason in self._raised:
            return
        self._raised.add(reason)
        self.fault = reason
        self.pending = (reason, action)

    def on_mode(self, previous: str | None, mode: str) -> bool:
        """A new HEARTBEAT's mode; True when the vehicle was taken out of OFFBOARD by someone
        else (the caller stops the setpoint stream at once)."""
        if self.offboard_engaged and previous == FlightMode.OFFBOARD.value and mode != previous \
                and self.expected_mode != mode:
            reason = f"mode changed from OFFBOARD to {mode} outside our control"
            self.commanding_stopped = reason
            self.offboard_engaged = False
            self.raise_failsafe(reason, "offboard commanding stopped")
            return True
        return False

    def check(self, telemetry: TelemetryStore, now: float) -> bool:
        """Link, position and battery checks at wall time ``now``; True when the heartbeat
        is lost (the caller stops streaming)."""
        if telemetry.heartbeat is None:
            return False
        fs = self.settings
        if now - telemetry.heartbeat_wall > fs.link_loss_timeout:
            self.raise_failsafe(f"autopilot heartbeat lost for more than {fs.link_loss_timeout:g} s",
                                "setpoints stopped; the autopilot flies its own failsafe")
            return True
        armed = telemetry.armed
        # Stale position only while the link is provably alive: a heartbeat came
        # more than the stale timeout after the last position. A heartbeat that
        # merely happened to be the link's last message must not turn a silent
        # link into a stale-position hold (the heartbeat failsafe above owns that).
        if armed and now - telemetry.local_wall > fs.position_stale_timeout \
                and telemetry.heartbeat_wall - telemetry.local_wall > fs.position_stale_timeout:
            self.raise_failsafe(f"local position stale for more than {fs.position_stale_timeout:g} s", "hold")
        elif (armed and telemetry.battery is not None and telemetry.battery < fs.low_battery_fraction
              and not telemetry.on_ground):
            self.raise_failsafe(f"battery low ({telemetry.battery:.0%} < {fs.low_battery_fraction:.0%})",
                                fs.low_battery_action)
        return False

    def take_pending(self) -> tuple[str, str] | None:
        pending, self.pending = self.pending, None
        return pending
