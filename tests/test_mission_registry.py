"""The insulator registry's track confirmation: an insulator is registered (and
inspected) only after ``confirmations`` localizations within its gate."""

import numpy as np
import pytest

from insulator_rs import bounds
from insulator_rs.geodesy import line_frame
from insulator_rs.mission.config import InspectionParams
from insulator_rs.tracking.confirmation import CONFIRMATIONS, MIN_CONFIRMATIONS
from insulator_rs.tracking.registry import InsulatorRegistry

LINE = line_frame(np.array([[0.0, -280.0, 0.0], [0.0, 300.0, 1.5]]))  # along +y, lateral +x
REAL = np.array([5.0, -1.4, 16.9])
STEEL = np.array([2.0, 0.0, 15.5])  # a one-off localization on the lattice
AXIS = np.array([0.0, 1.0, 0.0])


def test_confirmed_on_the_third_localization_and_only_once():
    reg = InsulatorRegistry(LINE, gate=1.5, confirmations=3)
    outcomes = [reg.observe(REAL + 0.05 * k, AXIS)[1] for k in range(5)]
    assert outcomes == [False, False, True, False, False]
    assert len(reg) == 1 and reg.insulators[0].id == 1 and reg.insulators[0].observations == 5
    np.testing.assert_allclose(reg.insulators[0].center, REAL + 0.1, atol=1e-12)  # mean of 0..4 * 0.05


def test_a_one_off_localization_stays_a_candidate():
    reg = InsulatorRegistry(LINE, gate=1.5, confirmations=3)
    for _ in range(3):
        reg.observe(REAL, AXIS)
    ins, confirmed = reg.observe(STEEL, AXIS)
    assert not confirmed and not ins.confirmed
    assert [i.id for i in reg.insulators] == [1]
    assert len(reg.candidates) == 1 and reg.nearest(STEEL)[0] is reg.insulators[0]


def test_ids_follow_the_order_of_confirmation():
    reg = InsulatorRegistry(LINE, gate=1.5, confirmations=2)
    other = REAL + np.array([0.0, 3.0, 0.0])
    reg.observe(REAL, AXIS)
    reg.observe(other, AXIS)
    reg.observe(other, AXIS)   # `other` confirmed first
    reg.observe(REAL, AXIS)
    assert [(i.id, tuple(np.round(i.center, 3))) for i in reg.insulators] == [
        (1, tuple(other)), (2, tuple(REAL))]


def test_one_confirmation_is_the_paper_behaviour():
    reg = InsulatorRegistry(LINE, gate=1.5, confirmations=1)
    assert reg.observe(REAL, AXIS)[1] is True and len(reg) == 1


def test_the_default_is_the_missions():
    """One default for the registry and the mission file (tracking/confirmation.py): what flies."""
    reg = InsulatorRegistry(LINE, gate=1.5)
    assert reg.confirmations == CONFIRMATIONS == InspectionParams(standoff=8.0, safety_margin=2.0).confirmations
    assert [reg.observe(REAL, AXIS)[1] for _ in range(CONFIRMATIONS)] == [False] * (CONFIRMATIONS - 1) + [True]


def test_bad_confirmations_is_named():
    with pytest.raises(ValueError, match="confirmations"):
        InsulatorRegistry(LINE, gate=1.5, confirmations=0)
    with pytest.raises(ValueError, match="confirmations"):
        InsulatorRegistry(LINE, gate=1.5, confirmations=2.5)  # type: ignore[arg-type]


def test_the_registry_and_the_mission_file_share_one_bound():
    """The lowest count the mission file takes is the registry's lowest (bounds.py)."""
    assert MIN_CONFIRMATIONS == bounds.MISSION["inspection.confirmations"].lo == 1
    InsulatorRegistry(LINE, gate=1.5, confirmations=MIN_CONFIRMATIONS)
    with pytest.raises(ValueError, match="confirmations"):
        InsulatorRegistry(LINE, gate=1.5, confirmations=MIN_CONFIRMATIONS - 1)
