"""The autopilot's parameters for one flight: read the old values, set the tower's, verify each,
and put the old ones back after the landing; what happened to each goes into the summary.

The values are planning's (:mod:`insulator_rs.planning.px4_failsafes`); the wire is the vehicle
adapter's (the ``ParameterStore`` port: PARAM_SET verified by PARAM_VALUE). This module is the
order and the bookkeeping:

* every old value is read before anything is set, so a parameter PX4 lacks stops the flight
  before it changed anything;
* a set that fails puts back what was already set, then raises (the mission does not arm);
* the restore runs once the vehicle is on the ground; while PX4 still flies (its own failsafe,
  or a pilot holding after a hand-over) the tower's values stay: they are what keeps PX4's
  return over the tower. A restore that fails is reported per parameter, never raised.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

from insulator_rs.exceptions import ParameterError
from insulator_rs.planning.px4_failsafes import ParameterSetting
from insulator_rs.ports.vehicle import ParameterStore


@dataclass
class ParameterRecord:
    """One parameter's flight: the value before (``old``), the one set and verified (``set``),
    the one put back and verified (``restored``, None until then), ``why`` it was set, and
    ``error`` when a step failed."""

    name: str
    why: str
    old: int | float | None = None
    set: int | float | None = None
    restored: int | float | None = None
    error: str | None = None


class AutopilotSetup:
    """Applies ``settings`` to ``store`` and restores them (see the module docstring)."""

    def __init__(self, store: ParameterStore, settings: Sequence[ParameterSetting], *,
                 ground_station: bool) -> None:
        self.store = store
        self.settings = tuple(settings)
        self.ground_station = ground_station
        self.records = [ParameterRecord(s.name, s.why) for s in self.settings]
        self.restore_status = "not set yet"
        self.pending = False  # every value set, none put back yet: the restore is owed

    def apply(self) -> None:
        """Read every old value, then set and verify each; ParameterError (after undoing what was
        set) on the first that fails."""
        for record in self.records:
            try:
                record.old = self.store.read(record.name)
            except ParameterError as exc:
                record.error = str(exc)
                self.restore_status = "nothing set: an old value could not be read"
                raise
        for record, setting in zip(self.records, self.settings):
            try:
                record.set = self.store.set(setting.name, setting.value)
            except ParameterError as exc:
                record.error = str(exc)
                self.restore()
                self.restore_status = f"set failed at {setting.name}; {self.restore_status}"
                raise
        self.restore_status = "set; not restored yet"
        self.pending = True

    def restore(self) -> None:
        """Put every old value back that was changed (verified); failures are recorded, not raised.
        An autopilot that answers none of the tries for one value (the link is gone: the fault
        matrix's link loss at take-off waited minutes on every parameter's retries) is not asked
        for the rest: they are recorded as failed too."""
        failed = []
        self.pending = False
        unheard: str | None = None
        for record in self.records:
            if record.set is None or record.old is None:
                continue
            if unheard is not None:
                record.error = f"not tried: {unheard}"
                failed.append(record.name)
                continue
            try:
                record.restored = self.store.set(record.name, record.old)
            except ParameterError as exc:
                record.error = str(exc)
                failed.append(record.name)
                if "no PARAM_VALUE" in exc.reason or "not confirmed" in exc.reason:
                    unheard = f"the autopilot did not answer for {record.name}"
        self.restore_status = f"restore failed for {', '.join(failed)}" if failed else "restored"

    def keep(self, reason: str) -> None:
        """Leave the tower's values set (the vehicle still flies): say why in the report."""
        self.restore_status = f"not restored: {reason}"
        self.pending = False

    def record(self) -> dict[str, Any]:
        """The summary's ``px4_parameters``."""
        return {"ground_station": self.ground_station, "restore": self.restore_status,
                "parameters": [asdict(r) for r in self.records]}
