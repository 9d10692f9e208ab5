"""The online state machine, registry and waypoints on scripted event sequences."""

import math

import numpy as np
import pytest

from insulator_rs.planning.exploration import exploration_path
from insulator_rs.geodesy import line_frame
from insulator_rs.planning.pmm import rest_to_rest_times
from insulator_rs.tracking.registry import InsulatorRegistry
from insulator_rs.planning.safety import safety_volumes
from insulator_rs.mission.state_machine import InspectionStateMachine, State
from insulator_rs.planning.waypoints import inspection_waypoints

LINE = line_frame(np.array([[0.0, -280.0, 0.0], [0.0, 300.0, 1.5]]))  # along +y, lateral +x
VOL = safety_volumes(LINE, max_width=10.0, max_height=31.0, margin=2.0)
TAKEOFF = np.array([13.0, 0.0, 0.0])
NEAR = np.array([5.0, -1.4, 16.9])    # + side (the take-off side)
NEAR2 = np.array([5.0, 1.4, 20.9])
FAR = np.array([-5.0, -1.4, 16.9])
AXIS = np.array([0.0, 1.0, 0.1])


def machine(policy="immediate", per_insulator=2):
    path = exploration_path(LINE, VOL, takeoff=TAKEOFF, max_width=10.0, max_height=31.0, standoff=8.0,
                            pass_spacing=8.0, crossing_clearance=3.0)
    reg = InsulatorRegistry(LINE, gate=1.5, confirmations=1)  # the paper: at once

    def make(ins):
        return inspection_waypoints(ins.center, ins.axis, insulator_id=ins.id, line=LINE, volumes=VOL,
                                    count=per_insulator, inspection_distance=6.0, insulator_length=2.2,
                                    fov=math.radians(60))

    def cost(a, b):
        return float(rest_to_rest_times(a, b, 3.0, 12.0))

    sm = InspectionStateMachine(path, reg, make, policy=policy, cost=cost)
    sm.start(0.0)
    return sm


def fly_to_end(sm, t=1.0):
    kinds = []
    while not sm.done:
        kinds.append(sm.reached(t).kind)
        t += 1.0
    return kinds


def test_plain_exploration_visits_the_path_and_finishes():
    sm = machine()
    assert sm.state == State.EXPLORE
    n = len(sm.plan)
    kinds = fly_to_end(sm)
    assert len(kinds) == n and kinds[-1] == "land"
    states = [tr.target for tr in sm.transitions]
    assert states[:1] == [State.EXPLORE] and State.CROSS in states and states[-1] == State.FINISH


def test_duplicate_detections_update_instead_of_adding():
    sm = machine()
    sm.reached(1.0)
    assert sm.localized(NEAR, AXIS, sm.visited[-1].position, 1.5) == "new"
    plan_len = len(sm.plan)
    for k in range(3):
        noisy = NEAR + np.array([0.3, -0.2, 0.1]) * (k - 1)
        assert sm.localized(noisy, -AXIS, sm.visited[-1].position, 2.0 + k) == "updated"
    assert len(sm.registry) == 1 and len(sm.plan) == plan_len
    ins = sm.registry.insulators[0]
    assert ins.observations == 4 and ins.axis @ AXIS > 0  # the flipped axes were sign-aligned
    np.testing.assert_allclose(ins.center, NEAR, atol=1e-9)  # the noise averaged out


def test_near_side_detection_starts_a_detour_and_returns_to_the_path():
    sm = machine()
    sm.reached(1.0)
    here = sm.visited[-1].position + np.array([0.0, 3.0, 0.0])  # between two path waypoints
    next_scan = sm.plan[0].position
    sm.localized(NEAR, AXIS, here, 2.0)
    assert sm.state == State.INSPECT
    assert [it.kind for it in sm.plan[:3]] == ["inspect", "inspect", "return"]
    np.testing.assert_allclose(sm.plan[2].position, here)
    for it in sm.plan[:2]:
        assert it.waypoint.side == 1 and VOL.points_clear(it.position[None])[0]
        assert abs(np.linalg.norm(it.position - NEAR) - 6.0) < 1e-9
    sm.reached(3.0), sm.reached(4.0)
    assert sm.state == State.RETURN and sm.registry.insulators[0].inspected
    sm.reached(5.0)
    assert sm.state == State.EXPLORE
    np.testing.assert_allclose(sm.plan[0].position, next_scan)


def test_detection_during_a_detour_joins_the_detour():
    sm = machine()
    sm.reached(1.0)
    sm.localized(NEAR, AXIS, sm.visited[-1].position, 2.0)
    sm.reached(3.0)  # first viewpoint of insulator 1
    sm.localized(NEAR2, AXIS, sm.visited[-1].position, 3.5)
    assert sm.state == State.INSPECT
    kinds = [it.kind for it in sm.plan[:5]]
    assert kinds == ["inspect", "inspect", "inspect", "return", "scan"]  # one return only
    assert [it.waypoint.insulator_id for it in sm.plan[:3]] == [1, 2, 2]


def test_far_side_insulator_is_deferred_until_the_vehicle_crosses():
    sm = machine()
    sm.reached(1.0)
    plan_len = len(sm.plan)
    assert sm.localized(FAR, AXIS, sm.visited[-1].position, 2.0) == "deferred"
    assert sm.state == State.EXPLORE and len(sm.plan) == plan_len and len(sm.deferred[-1]) == 2
    t = 3.0
    while sm.side == 1:
        sm.reached(t)
        t += 1
    # just arrived on side -1: the deferred waypoints are visited now, then back to that point
    assert sm.state == State.INSPECT and not sm.deferred
    assert [it.kind for it in sm.plan[:3]] == ["inspect", "inspect", "return"]
    assert all(it.side == -1 for it in sm.plan[:3])
    kinds = fly_to_end(sm, t)
    assert kinds.count("inspect") == 2 and sm.registry.insulators[0].inspected


def test_insertion_policy_defers_the_visit_to_where_it_is_cheap():
    sm = machine("insertion", per_insulator=1)
    sm.reached(1.0)  # first pass corner (a = -7, z = 7)
    sm.localized(NEAR2, AXIS, sm.visited[-1].position, 2.0)  # z = 20.9: near the third pass
    kinds = [it.kind for it in sm.plan]
    k = kinds.index("inspect")
    assert k > 0 and "return" not in kinds
    assert sm.plan[k - 1].position[2] > 15 and sm.state == State.EXPLORE
    total = fly_to_end(sm)
    assert total.count("inspect") == 1


def test_hold_resume_abort_are_logged():
    sm = machine()
    sm.reached(1.0)
    sm.fault("localization lost", 2.0)
    assert sm.state == State.HOLD and sm.target() is None
    with pytest.raises(RuntimeError, match="reached"):
        sm.reached(2.5)
    sm.resume(3.0)
    assert sm.state == State.EXPLORE
    sm.abort("battery low", 4.0)
    assert sm.done and sm.localized(NEAR, AXIS, TAKEOFF, 5.0) == "ignored"
    reasons = [(t.source, t.target) for t in sm.transitions]
    assert (State.EXPLORE, State.HOLD) in reasons and (State.HOLD, State.EXPLORE) in reasons
    assert reasons[-1] == (State.EXPLORE, State.ABORT)


def test_bad_arguments():
    with pytest.raises(ValueError, match="policy"):
        InspectionStateMachine(machine().path, InsulatorRegistry(LINE, 1.0), lambda i: [], policy="x")
    with pytest.raises(ValueError, match="gate"):
        InsulatorRegistry(LINE, 0.0)
    with pytest.raises(ValueError, match="count"):
        inspection_waypoints(NEAR, AXIS, insulator_id=1, line=LINE, volumes=VOL, count=0,
                             inspection_distance=6.0, insulator_length=2.2, fov=1.0)


def test_viewpoints_aim_at_the_insulator_and_see_it_whole():
    wps = inspection_waypoints(NEAR, AXIS, insulator_id=1, line=LINE, volumes=VOL, count=3,
                               inspection_distance=2.0, insulator_length=2.2, fov=math.radians(40))
    for w in wps:
        d = w.target - w.position
        assert math.isclose(math.atan2(d[1], d[0]), w.yaw, abs_tol=1e-12)
        assert math.isclose(math.atan2(d[2], math.hypot(d[0], d[1])), w.gimbal_pitch, abs_tol=1e-12)
        dist = np.linalg.norm(d)
        # half the insulator subtends no more than the allowed fraction of half the FOV
        assert math.atan(1.1 / dist) <= 0.7 * math.radians(20) + 1e-9
        assert abs(d @ AXIS) < 1e-6 * dist * 10  # perpendicular to the axis
        assert VOL.points_clear(w.position[None])[0] and w.position[0] > 5  # near (+) side


def test_an_unreachable_inspection_waypoint_is_skipped_not_the_mission():
    """``skip`` drops one inspection waypoint: its insulator stays uninspected, the reason is kept,
    the plan goes on to the end; anything but a planned inspection waypoint is refused."""
    sm = machine()
    sm.localized(NEAR, AXIS, TAKEOFF, 1.0)
    assert sm.state == State.INSPECT
    first = sm.plan[0]
    assert first.kind == "inspect"
    with pytest.raises(RuntimeError, match="only a planned inspection waypoint"):
        sm.skip(next(it for it in sm.plan if it.kind == "scan"), 2.0, "x")
    sm.skip(first, 2.0, "no safe trajectory")
    assert sm.skipped == [(first, "no safe trajectory")] and all(it is not first for it in sm.plan)
    with pytest.raises(RuntimeError):
        sm.skip(first, 2.5, "again")  # no longer planned
    kinds = fly_to_end(sm, 3.0)
    assert kinds[-1] == "land" and kinds.count("inspect") == 1
    assert not sm.registry.insulators[0].inspected


def test_reaching_an_item_a_find_has_displaced_is_refused():
    """The flight reports the item it flew to; a find since then put its inspection waypoints
    in front of it, so reaching it must not count the new head (an unflown waypoint) as done."""
    sm = machine()
    flown_to = sm.target()
    assert sm.localized(NEAR, AXIS, flown_to.position, 1.0) == "new"
    assert sm.target() is not flown_to and sm.target().kind == "inspect"
    with pytest.raises(RuntimeError, match="no longer the plan's head"):
        sm.reached(1.5, flown_to)
    assert sm.reached(2.0, sm.target()).kind == "inspect"  # the head itself is reached as before


def test_unconfirmed_localizations_are_reported_as_candidates():
    """What the registry holds without its confirmations goes to the summary's ``candidates``
    (most observed first), so the crew knows where a string may hang that the run never confirmed."""
    from insulator_rs.flight.record import candidate_records

    reg = InsulatorRegistry(LINE, gate=1.5, confirmations=3)
    reg.observe(NEAR, AXIS)
    reg.observe(FAR, AXIS), reg.observe(FAR + 0.1, AXIS)
    for _ in range(3):
        reg.observe(NEAR2, AXIS)  # confirmed: an insulator, not a candidate
    got = candidate_records(reg)
    assert [c["observations"] for c in got] == [2, 1]
    np.testing.assert_allclose(got[0]["center"], FAR + 0.05)
    assert got[0]["side"] == -1 and got[1]["side"] == 1
    assert len(reg.insulators) == 1
