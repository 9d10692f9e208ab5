"""The MAVLink parameter protocol: PARAM_REQUEST_READ / PARAM_SET, each answered by PARAM_VALUE.

What PX4 v1.16.0 does (measured on its SITL, ``tests/test_px4_sitl_parameters.py``), and so what
this module expects:

* values travel in PARAM_VALUE's float field **bytewise** (AUTOPILOT_VERSION advertises
  MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE): an INT32 parameter's four bytes are the int's,
  reinterpreted as a float. A C-cast 3.0 sent for an INT32 parameter is taken as the int
  1077936128, so the encoding is never guessed: :func:`encode` / :func:`decode`;
* a PARAM_SET must carry the parameter's own MAV_PARAM_TYPE: with another one PX4 logs "param
  types mismatch" and answers nothing. The type is learnt from PX4's PARAM_VALUE (a read comes
  first, always);
* a name PX4 does not have (names are case-sensitive) gets no answer at all, read or set;
* a set is answered with PARAM_VALUE (twice: the reply and the change broadcast); PX4 does not
  clamp to the documented range (RTL_RETURN_ALT 1000 was taken), so ranges are the planner's job.

MAVLink is lossy: a request is resent ``retries`` times, ``timeout`` s apart (wall seconds), before
:class:`~insulator_rs.exceptions.ParameterError` names the parameter. No answer is ever a
traceback of pymavlink's: every failure is that one exception.
"""

from __future__ import annotations

import math
import struct
import threading
import time
from dataclasses import dataclass
from typing import Any

from insulator_rs.exceptions import ParameterError
from insulator_rs.mavlink.link import AutopilotLink
from insulator_rs.mavlink.wire import mavlink2

M = mavlink2
PARAM_ID_LENGTH = 16  # MAVLink's char[16]: a 16-character name has no terminating NUL
INTEGER_TYPES = frozenset({M.MAV_PARAM_TYPE_INT32, M.MAV_PARAM_TYPE_UINT32, M.MAV_PARAM_TYPE_INT16,
                           M.MAV_PARAM_TYPE_UINT16, M.MAV_PARAM_TYPE_INT8, M.MAV_PARAM_TYPE_UINT8})
# s: a ground station whose HEARTBEAT (1 Hz) is older than this is not counted as present
GROUND_STATION_FRESH_S = 3.0
_INT_FORMATS = {M.MAV_PARAM_TYPE_INT32: "<i", M.MAV_PARAM_TYPE_UINT32: "<I", M.MAV_PARAM_TYPE_INT16: "<h",
                M.MAV_PARAM_TYPE_UINT16: "<H", M.MAV_PARAM_TYPE_INT8: "<b", M.MAV_PARAM_TYPE_UINT8: "<B"}


@dataclass(frozen=True)
class ParameterValue:
    """One parameter as the autopilot reported it: ``value`` an int for integer types, a float
    for REAL32; ``param_type`` the MAV_PARAM_TYPE."""

    name: str
    value: int | float
    param_type: int


def check_name(name: object) -> str:
    """A parameter name fit for the wire: a non-empty ASCII string of at most 16 characters."""
    if not isinstance(name, str) or not name or len(name) > PARAM_ID_LENGTH or not name.isascii():
        raise ValueError(f"parameter name must be 1-{PARAM_ID_LENGTH} ASCII characters, got {name!r}")
    return name


def decode(raw: float, param_type: int) -> int | float:
    """PARAM_VALUE's float field as the parameter's value (bytewise for integer types)."""
    fmt = _INT_FORMATS.get(param_type)
    if fmt is None:
        return float(raw)
    data = struct.pack("<f", raw)
    return int(struct.unpack(fmt, data[:struct.calcsize(fmt)])[0])


def encode(name: str, value: int | float, param_type: int) -> float:
    """``value`` in PARAM_SET's float field for a parameter of ``param_type`` (bytewise for
    integer types). Raises ParameterError naming ``name`` when the value does not fit the type,
    or its bytes would not survive the float field (an int whose bytes are a signalling NaN:
    the host's float conversions would change them)."""
    fmt = _INT_FORMATS.get(param_type)
    if fmt is None:
        if param_type != M.MAV_PARAM_TYPE_REAL32:
            raise ParameterError(name, f"MAV_PARAM_TYPE {param_type} is not supported")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ParameterError(name, f"a REAL32 parameter needs a finite number, got {value!r}")
        try:
            struct.pack("<f", float(value))
        except OverflowError:
            raise ParameterError(name, f"{value!r} does not fit a 32-bit float") from None
        return float(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or float(value) != int(value):
        raise ParameterError(name, f"an integer parameter needs an integral value, got {value!r}")
    try:
        data = struct.pack(fmt, int(value)).ljust(4, b"\0")
    except struct.error:
        raise ParameterError(name, f"{value!r} is out of range for its MAV_PARAM_TYPE {param_type}") from None
    raw = struct.unpack("<f", data)[0]
    if decode(raw, param_type) != int(value):
        raise ParameterError(name, f"{value!r} cannot be carried bytewise in MAVLink's float field")
    return raw


def same_value(a: int | float, b: int | float, param_type: int) -> bool:
    """Equal as the autopilot stores them (integers exactly, REAL32 as 32-bit floats)."""
    if param_type in INTEGER_TYPES:
        return int(a) == int(b)
    return struct.pack("<f", float(a)) == struct.pack("<f", float(b))


class ParameterProtocol:
    """Reads and sets the autopilot's parameters over ``link``; PARAM_VALUE messages come in
    through :meth:`on_value`, called by the client's receiver under ``condition``'s lock (the
    client's lock, notified after each message)."""

    def __init__(self, link: AutopilotLink, condition: threading.Condition, stop: threading.Event, *,
                 timeout: float, retries: int) -> None:
        if not isinstance(retries, int) or retries < 1:
            raise ValueError(f"parameter retries must be an int >= 1, got {retries!r}")
        self.link = link
        self.timeout = timeout
        self.retries = retries
        self._condition = condition
        self._stop = stop
        self._values: dict[str, tuple[int, ParameterValue]] = {}  # name -> (arrival number, value)
        self._arrivals = 0
        self.known: dict[str, ParameterValue] = {}  # the last value read or verified, by name
        self._ground_station_at: float | None = None  # wall time of the last GCS HEARTBEAT heard

    def on_value(self, msg: Any) -> None:
        """A PARAM_VALUE from the autopilot (under the condition's lock)."""
        name = str(msg.param_id)
        try:
            value = decode(float(msg.param_value), int(msg.param_type))
        except (struct.error, ValueError, TypeError, OverflowError):
            return  # a value this side cannot decode is not an answer to anything we asked
        self._arrivals += 1
        self._values[name] = (self._arrivals, ParameterValue(name, value, int(msg.param_type)))

    def on_ground_station_heartbeat(self) -> None:
        """A ground station's HEARTBEAT came over the autopilot's link (one assignment: no lock)."""
        self._ground_station_at = time.monotonic()

    def ground_station(self, wait: float) -> bool:
        """Whether a ground station's HEARTBEAT (1 Hz) came within the last ``GROUND_STATION_FRESH_S``
        s, waiting up to ``wait`` s for one. PX4 forwards a GCS's HEARTBEAT to the onboard link
        (measured on v1.16.0 SITL), so the companion hears the ground station PX4 hears."""
        deadline = time.monotonic() + max(0.0, float(wait))
        with self._condition:
            while True:
                heard = self._ground_station_at
                if heard is not None and time.monotonic() - heard < GROUND_STATION_FRESH_S:
                    return True
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self._stop.is_set():
                    return False
                self._condition.wait(timeout=min(remaining, 0.1))

    def read(self, name: str) -> int | float:
        """The parameter's value as the autopilot reports it (the ``ParameterStore`` port)."""
        return self.fetch(name).value

    def set(self, name: str, value: int | float) -> int | float:
        """Set and verify (the ``ParameterStore`` port); the value the autopilot reports."""
        return self.write(name, value).value

    def fetch(self, name: str) -> ParameterValue:
        """PARAM_REQUEST_READ by name; the autopilot's PARAM_VALUE (value and type)."""
        name = check_name(name)
        value = self._exchange(name, lambda: self._send_read(name), lambda v: True)
        if value is None:
            raise ParameterError(name, f"no PARAM_VALUE after {self.retries} tries of {self.timeout:g} s: "
                                       "the autopilot has no parameter of that name, or the link lost every answer")
        self.known[name] = value
        return value

    def write(self, name: str, value: int | float) -> ParameterValue:
        """PARAM_SET ``value`` with the parameter's own type (read first if not known yet); returns
        the PARAM_VALUE that shows it set. Raises ParameterError when the autopilot keeps another
        value or never answers."""
        name = check_name(name)
        current = self.known.get(name) or self.fetch(name)
        raw = encode(name, value, current.param_type)
        target = decode(raw, current.param_type)
        answer = self._exchange(name, lambda: self._send_set(name, raw, current.param_type),
                                lambda v: same_value(v.value, target, current.param_type))
        if answer is None:
            last = self._values.get(name)
            seen = f"; it reports {last[1].value!r}" if last is not None else ""
            raise ParameterError(name, f"set to {value!r} not confirmed by PARAM_VALUE after {self.retries} tries "
                                       f"of {self.timeout:g} s{seen}")
        self.known[name] = answer
        return answer

    def _exchange(self, name: str, send: Any, accept: Any) -> ParameterValue | None:
        """Send, wait for a PARAM_VALUE of ``name`` newer than the send that ``accept`` takes;
        resend on timeout. None after every try."""
        for _ in range(self.retries):
            with self._condition:
                mark = self._arrivals
            send()
            deadline = time.monotonic() + self.timeout
            with self._condition:
                while not self._stop.is_set():
                    entry = self._values.get(name)
                    if entry is not None and entry[0] > mark and accept(entry[1]):
                        return entry[1]
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        break
                    self._condition.wait(timeout=remaining)
            if self._stop.is_set():
                return None
        return None

    def _target(self) -> tuple[int, int]:
        return self.link.autopilot or (self.link.target_system or 1, 1)

    def _send_read(self, name: str) -> None:
        self.link.send("param_request_read", *self._target(), name.encode("ascii"), -1)

    def _send_set(self, name: str, raw: float, param_type: int) -> None:
        self.link.send("param_set", *self._target(), name.encode("ascii"), raw, param_type)
