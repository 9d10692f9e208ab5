"""The second look: before the search ends, a string seen too few times to be confirmed is
flown to and watched for a few detection events.

Why: at the mission's defaults (4 confirmations, 1 Hz detection) the live-sensor flight
against PX4 SITL missed the far-side string of the small scene in 7 of 25 flights, and in the
misses whose summary listed candidates (session 13, CI's among them) the string was there, an
unconfirmed candidate seen 2-3 times within 0.2 m of the truth. The last side's passes are
its only chance: once the search ends a find only refines the registry.

Where from: not the photo's viewpoint. Replayed box by box, the live network at 320 x 240 boxes
a string 6 m off at its own height in fragments (15 px, refused by the scale check), while the
passes, 6-8 m off and 1-2 m below, gave whole boxes (26-37 px, 8-18 LiDAR returns): the look
watches from :data:`LOOK_DISTANCE` out and :data:`LOOK_BELOW` under the candidate. And from more
than one place: a hover's frames fail together (session 14, soak 4: at one viewpoint 4 of 9
frames boxed nothing on the string and 2 boxed a fragment; the look gained 2 localizations of
the 3 it lacked), so when one view has not confirmed it the look moves :data:`LOOK_SHIFT` along
the line (about 27 degrees round the candidate: another background, another box) and watches
again, up to :data:`LOOK_VIEWS` views.

When: where a side's search ends (the last pass corner before the crossing) and where the
whole search ends, once perception has handed on the frames taken up to there. Session 14's
first soak flight missed the far-side string seen once in its side's passes (a candidate
1 time, 0.02 m from the truth), while the near string, seen as seldom in its passes, got 19
localizations hovering at its inspection waypoints: the distance and the hover make the
difference, so a candidate seen once is looked at too.

Which candidates: on the side the vehicle is on (the other side's passes are behind the
crossing), and off the tower's body. The last rule because the small tower's peak (a lattice on
the tower's axis) is a 1-2-time candidate in every live flight, and tower A's body members at
1.4-2.1 m from the axis were candidates too: looked at, they cost a minute each and could be
confirmed as false finds. A string hangs from an arm's tip: a tower's widest arms reach
``max_width / 2`` and its body at the arms' heights is far narrower, so a candidate within
:data:`BODY_FRACTION` of ``max_width`` of the axis (laterally, across the line) is taken for the
body. The fraction sits between the body's steel and the strings as measured: tower B's legs,
looked at live in session 15 (3 views each, never confirmed), at 2.28-2.31 m across the line
(0.25-0.26 of its 9 m), its upper strings at 3.5 m (0.39); tower A's body members at 0.14-0.21 of
its 10 m, its strings from 0.42; the small scene's peak at 0.07-0.15 of its 6 m, its strings at
0.5. A body wider near the ground than the fraction (a tower's legs spread to its base) still
offers its lowest steel to a look. At most :data:`MAX_LOOKS` a flight, the most seen first: a view is about
15 s of flight, a look at most :data:`LOOK_VIEWS` of them. The registry's candidates come first,
then the tracks the gates refused throughout, then (with the mission's ``lidar_cue``) the strings
the LiDAR's geometry found that no camera track covers (:mod:`insulator_rs.flight.lidar_cue`): a
look there is how the camera gets its chance at a string it never boxed on the passes, and only
the camera's localizations, in the registry, confirm it.

Only what the battery spares: a look is flown where the latest weighing of the reserve still
covers the look (there and back, each view watched to its limit), then the rest of the plan
and the reserve. A look is a chance at a string the passes may have missed; the plan's
inspections and the search's end are not traded for it. Tower A's default flight drew three
looks at refused tracks on its cross-arms and conductors (3 views each, nothing new found), and
the reserve then turned it back with every string inspected and the search's last 56 m unflown.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import KW_ONLY, dataclass, field
from typing import Any

import numpy as np

from insulator_rs.exceptions import PlanningError
from insulator_rs.flight.energy_budget import EnergyBudget
from insulator_rs.flight.leg_follower import LegFollower
from insulator_rs.flight.photo_session import PHOTO_SETTLE_TIMEOUT, settle
from insulator_rs.flight.pilot import CONTROL_PERIOD, Pilot
from insulator_rs.geodesy import LineFrame
from insulator_rs.mission.config import Mission
from insulator_rs.mission.geometry import MissionGeometry
from insulator_rs.mission.state_machine import PlanItem, State
from insulator_rs.perception.pairing import PAIRING_WAIT
from insulator_rs.perception.runner import PerceptionRunner
from insulator_rs.planning.exploration import MIN_PASS_HEIGHT, PATH_CLEARANCE, PlanKind
from insulator_rs.planning.safety import SafetyVolumes
from insulator_rs.perception.pipeline import EVENTS_PER_LOCALIZATION
from insulator_rs.tracking.confirmation import localizations_missing
from insulator_rs.tracking.registry import Insulator, InsulatorRegistry

#: looks a flight at most
MAX_LOOKS = 3
#: detection events watched beyond the least that could confirm (a frame cut by the image edge,
#: a box the scale check refuses): session 14's first live look watched 5 events and got one
#: localization, the pipeline's new track needing EVENTS_PER_LOCALIZATION events first
LOOK_MARGIN_EVENTS = 3
#: a candidate closer to the tower's axis than this share of ``max_width`` is on its body
BODY_FRACTION = 0.3
#: m, horizontally out from the candidate across the line, and below it: where the passes
#: localized strings (session 14's replay, box by box: 6-8 m off and 1-2.5 m below, whole boxes
#: of 26-37 px with 8-18 LiDAR returns) and not where the photo is taken (6 m off at the
#: string's height: boxes of its parts, 15 px, refused by the scale check, 2 localizations in
#: 18 s). Below, the Mid-360's field of view (-7 to +52 deg) holds the whole string.
LOOK_DISTANCE = 7.0
LOOK_BELOW = 2.0
#: m: how far past LOOK_DISTANCE the viewpoint may move out to clear the safety volumes
LOOK_MAX_PUSH = 10.0
#: views a look at most: straight out, then LOOK_SHIFT along the line either way
LOOK_VIEWS = 3
#: m along the line between views (at LOOK_DISTANCE: about 27 degrees round the candidate)
LOOK_SHIFT = 3.5
#: confident boxes (BIRTH_SCORE or more) a track needs to be looked at when the gates refused
#: every localization it tried. Session 21's live miss: the small scene's first-side string
#: boxed 4 times at 0.5 or more (best 0.78), all 5 attempts refused (box fragments of 15x19 and
#: 5x25 px: the scale check; "not linear"), so it never reached the registry and got no look;
#: the track's anchor lay 0.10 m from the string. On tower A's default flight the tracks so
#: refused that lie off the body (the body's own, at the cross-arms' roots, up to 29, are left
#: out by BODY_FRACTION) had at most 2 confident boxes while the pipeline refused an ambiguous
#: box only after its other gates; with the bounded method refusing it first (in the core), 3
#: such tracks had 3: on a cross-arm and on a conductor past a strain string. They drew three
#: looks of 3 views that found nothing, and the battery reserve ended the flight with the
#: search's last 56 m unflown. Between the two: 4.
REFUSED_TRACK_MIN_CONFIDENT = 4
#: m from a known string (a registry record's segment, its centre +- half the mission's string
#: length along its axis) within which a refused track's anchor is taken for that string and not
#: looked at. Tower A with the ground-truth stand-in at detect scale 0.2 (session 23): two such
#: tracks, anchored on the cross-arm tip at the strain strings' inner ends (0.90 and 1.15 m from
#: found strings), drew two looks of 3 views that found nothing new, and the battery reserve
#: ended the flight before its last inspection. The nearest other string there (the strain
#: pair's twin, centres 2.87 m apart along the line) keeps its middle 1.27 m or more away.
KNOWN_STRING_REACH = 1.25


@dataclass(frozen=True)
class SecondLook:
    """One look, for summary.json: the candidate (registry id, 0 unless confirmed; centre in W) and its
    localizations before and after, whether it was confirmed, the views it was watched from, and
    why a look was cut short or not flown (None: flown to its end)."""

    insulator_id: int
    center: np.ndarray
    observations_before: int
    observations_after: int
    confirmed: bool
    note: str | None = None
    views: int = 0
    #: "candidate" (a registry record), "refused track" (:func:`refused_track_candidate`) or
    #: "lidar string" (a string of the LiDAR cue no camera track covers: flight/lidar_cue.py)
    source: str = "candidate"

    def as_record(self) -> dict[str, Any]:
        return {"insulator_id": self.insulator_id, "center": np.round(self.center, 3).tolist(),
                "observations_before": self.observations_before, "observations_after": self.observations_after,
                "confirmed": self.confirmed, "views": self.views, "note": self.note, "source": self.source}


def refused_track_candidate(anchor: np.ndarray, line: LineFrame) -> Insulator:
    """A look target for a track the gates refused throughout (no registry record: id 0, seen 0
    times, no axis yet) at its ``anchor`` in W: the median of its boxes' nearest LiDAR returns."""
    center = np.asarray(anchor, dtype=np.float64).reshape(3).copy()
    return Insulator(id=0, center=center, axis=np.zeros(3), observations=0, side=line.side(center))


def string_distance(point: np.ndarray, record: Insulator, length: float) -> float:
    """m from ``point`` (W) to a record's string: the segment of ``length`` m along its axis
    through its centre (its centre alone when it has no axis)."""
    d = np.asarray(point, dtype=np.float64).reshape(3) - record.center
    norm = float(np.linalg.norm(record.axis))
    if norm > 0:
        along = float(d @ record.axis) / norm
        d = d - record.axis / norm * float(np.clip(along, -0.5 * length, 0.5 * length))
    return float(np.linalg.norm(d))


def near_a_known_string(anchor: np.ndarray, records: list[Insulator], length: float,
                        reach: float = KNOWN_STRING_REACH) -> bool:
    """Whether ``anchor`` (W) lies within ``reach`` m of a record's string (:func:`string_distance`)."""
    return any(string_distance(anchor, r, length) <= reach for r in records)


def observations_near(records: list[Insulator], center: np.ndarray, gate: float) -> int:
    """The localizations of the registry record within ``gate`` m of ``center`` (the most seen;
    0 when none): what a look at a refused track gathered."""
    c = np.asarray(center, dtype=np.float64)
    return max((r.observations for r in records if float(np.linalg.norm(r.center - c)) <= gate), default=0)


def look_target(candidates: list[Insulator], line: LineFrame, position: np.ndarray, max_width: float,
                looked: list[Insulator]) -> Insulator | None:
    """The candidate to look at next from ``position`` (W), the search ending there: of the
    registry's unconfirmed ``candidates``, those on ``position``'s side of the line and off the
    body, not in ``looked`` (the records themselves:
    a candidate's id is 0 until it is confirmed); the most seen.
    None when there is none or MAX_LOOKS are spent."""
    if len(looked) >= MAX_LOOKS:
        return None
    side = line.side(position)
    off_body = BODY_FRACTION * max_width
    eligible = [c for c in candidates
                if not any(c is seen for seen in looked) and not c.confirmed
                and line.side(c.center) == side and abs(float(line.to_line(c.center)[1])) >= off_body]
    return max(eligible, key=lambda c: c.observations, default=None)


def look_events(confirmations: int, observations: int) -> int:
    """Detection events to watch a candidate seen ``observations`` times for, once settled at
    its viewpoint: the localizations it still lacks (the registry confirms at ``confirmations``),
    the events a new track of the pipeline accumulates before its first, and the margin. The
    look ends sooner when the candidate is confirmed."""
    return max(localizations_missing(observations, confirmations), 1) + EVENTS_PER_LOCALIZATION - 1 + LOOK_MARGIN_EVENTS


def look_viewpoints(center: np.ndarray, line: LineFrame, volumes: SafetyVolumes, *,
                    min_height: float) -> list[tuple[np.ndarray, float]]:
    """Where to watch a candidate at ``center`` (W) from, in order, each with the yaw that faces
    it: LOOK_DISTANCE out across the line on its side and LOOK_BELOW under it (not under
    ``min_height``), then LOOK_SHIFT along the line either way; each moved out in 0.5 m steps
    until PATH_CLEARANCE from ``volumes``, and left out when no point within LOOK_MAX_PUSH is
    clear. PlanningError when none is."""
    c = np.asarray(center, dtype=np.float64).reshape(3)
    out = line.side(c) * np.asarray(line.lateral, dtype=np.float64)
    along = np.asarray(line.along, dtype=np.float64)
    z = max(float(c[2]) - LOOK_BELOW, min_height)
    views = []
    for shift in (0.0, LOOK_SHIFT, -LOOK_SHIFT)[:LOOK_VIEWS]:
        for push in np.arange(0.0, LOOK_MAX_PUSH + 1e-9, 0.5):
            p = c + out * (LOOK_DISTANCE + push) + along * shift
            p[2] = z
            if bool(volumes.points_clear(p[None, :], PATH_CLEARANCE)[0]):
                views.append((p, math.atan2(float(c[1] - p[1]), float(c[0] - p[0]))))
                break
    if not views:
        raise PlanningError(f"no viewpoint clear of the safety volumes within {LOOK_DISTANCE + LOOK_MAX_PUSH:.0f} m "
                            f"of the candidate at {np.round(c, 2).tolist()}")
    return views


@dataclass(eq=False)
class SecondLookFlight:
    """Where the search (or a side's passes) ends: the hover until perception has caught up, then
    the second looks (see the module docstring); ``looks``: each look, for summary.json."""

    pilot: Pilot
    legs: LegFollower
    _: KW_ONLY
    registry: InsulatorRegistry
    runner: PerceptionRunner
    geom: MissionGeometry
    mission: Mission
    detect_period: float  # s between detection events
    energy: EnergyBudget  # weighs a look against the rest of the plan and the reserve
    # the LiDAR cue's strings no camera track covers, as look targets (flight/lidar_cue.py; None: no cue)
    lidar_targets: Callable[[], list[Insulator]] | None = None
    looks: list[SecondLook] = field(default_factory=list, init=False)
    looked: list[Insulator] = field(default_factory=list, init=False)  # the candidates looked at (the records)
    # look targets made for the pipeline's refused tracks, one per track (``looked`` holds them)
    _refused_targets: dict[int, Insulator] = field(default_factory=dict, init=False)
    _search_end: PlanItem | None = field(default=None, init=False)  # where the search ended, once caught up

    def may_end(self, item: PlanItem) -> bool:
        """Before ``item``, the plan's head, is reported reached: True to go on. Where reaching it
        ends the search (only crossings back and the landing follow) and perception still holds
        frames taken up to now, the vehicle first hovers at ``item`` until they are handed on
        (:meth:`wait_for_perception`), and False says: re-plan from there (a find of those
        frames is inspected first; else the item is reached at once). Once per item. Then, there
        and where a side's passes end, a candidate the passes saw too few times gets a second
        look (:meth:`look`), and False: re-plan."""
        sm = self.pilot.sm
        ends_search = sm.head_ends_search()
        if not ends_search and not sm.head_ends_side():
            return True
        if ends_search and self._search_end is not item:
            self._search_end = item
            arrival = self.pilot.vehicle.state().time
            if not self.runner.caught_up(arrival):
                self.wait_for_perception(item, arrival)
                return False
        # where a side's passes end (perception caught up where the search ends): a string they
        # saw too few times is looked at again, one a call (False: re-plan from the viewpoint,
        # back here or to the find's waypoints)
        position = self.pilot.vehicle.state().position
        target = look_target(self.registry.candidates, self.geom.line, position, self.mission.max_width, self.looked)
        if target is None:  # then a track confidently boxed whose every localization was refused
            target = look_target(self.refused_candidates(), self.geom.line, position, self.mission.max_width,
                                 self.looked)
        lidar = False
        if target is None and self.lidar_targets is not None:  # then a string only the LiDAR found
            target = look_target(self.lidar_targets(), self.geom.line, position, self.mission.max_width, self.looked)
            lidar = target is not None
        if target is None:
            return True
        self.looked.append(target)
        self.look(target, lidar=lidar)
        return False

    def refused_candidates(self) -> list[Insulator]:
        """Look targets for the pipeline's tracks boxed REFUSED_TRACK_MIN_CONFIDENT times with
        confidence whose every localization the gates refused, at their anchors (the same record
        for a track at every call, so ``looked`` knows it), the most confident first; not those
        anchored on a string the registry already holds (a known string seen from its steel)."""
        known = self.registry.insulators + self.registry.candidates
        length = self.mission.inspection.insulator_length
        tracks = [t for t in self.runner.pipeline.refused_tracks(REFUSED_TRACK_MIN_CONFIDENT)
                  if not near_a_known_string(t.anchor, known, length)]
        tracks.sort(key=lambda t: -t.evidence.confident_boxes)
        for track in tracks:
            if id(track) not in self._refused_targets:
                self._refused_targets[id(track)] = refused_track_candidate(track.anchor, self.geom.line)
        return [self._refused_targets[id(t)] for t in tracks]

    def look(self, candidate: Insulator, *, lidar: bool = False) -> None:
        """Watch ``candidate`` from its look viewpoints in turn, each for :func:`look_events`
        detection events once settled, then wait for their LiDAR points; ended by a find (the plan
        changes: its waypoints come first), cut short by a hold, an abort, lost health or an
        obstacle on the way. The look goes into ``looks``. ``lidar``: the candidate is a string
        only the LiDAR cue found (no registry record)."""
        pilot = self.pilot
        before = candidate.observations
        refused = any(candidate is target for target in self._refused_targets.values())
        source = "lidar string" if lidar else "refused track" if refused else "candidate"
        try:
            views = look_viewpoints(candidate.center, self.geom.line, self.geom.volumes,
                                    min_height=float(self.geom.takeoff[2]) + MIN_PASS_HEIGHT)
        except PlanningError as exc:
            self.looks.append(SecondLook(candidate.id, candidate.center.copy(), before, before,
                                         candidate.confirmed, f"not flown: {exc}", source=source))
            return
        dwell = self.view_time(candidate)
        spare = self.energy.spare_after_detour(pilot.vehicle.state().position, [p for p, _ in views], dwell)
        if spare is not None and spare < 0.0:
            self.looks.append(SecondLook(candidate.id, candidate.center.copy(), before, before, candidate.confirmed,
                                         f"not flown: the battery keeps it for the plan (short by {-spare:.1%})",
                                         source=source))
            pilot.say(f"[{pilot.now():7.1f} s] no second look at a {source} at "
                      f"{np.round(candidate.center, 2).tolist()}: the battery keeps {-spare:.1%} too little")
            return
        seen = {"candidate": f"seen {before} times", "refused track": "boxed with confidence, every localization refused",
                "lidar string": "found by the LiDAR alone, no camera track near"}[source]
        pilot.say(f"[{pilot.now():7.1f} s] a second look at a {source} ({seen}) at "
                  f"{np.round(candidate.center, 2).tolist()}")
        version = pilot.sm.plan_version
        note, flown = None, 0
        for position, yaw in views:
            if note is not None or pilot.sm.plan_version != version:
                break  # cut short, or a find: its inspection follows (the look did its job)
            view = PlanItem(PlanKind.SCAN, position, yaw, candidate.side)
            note = self.watch_from(view, candidate, version)
            flown += 1
        st = pilot.vehicle.state()
        watched = st.time
        deadline = watched + self.runner.pipeline.pairing_window + PAIRING_WAIT
        # the last view's LiDAR points (a frame's come up to PAIRING_WAIT s after its window)
        while (note is None and pilot.sm.plan_version == version and st.time < deadline
               and not self.runner.caught_up(watched)):
            st = pilot.tick(view.position, None, view.yaw)
            note = self._cut_short(version)
        after, confirmed = candidate.observations, candidate.confirmed
        if source != "candidate":  # what the registry now holds where the track or the LiDAR's string was
            gate = self.registry.gate
            after = observations_near(self.registry.insulators + self.registry.candidates, candidate.center, gate)
            confirmed = observations_near(self.registry.insulators, candidate.center, gate) > 0
        self.looks.append(SecondLook(candidate.id, candidate.center.copy(), before, after, confirmed, note,
                                     flown, source=source))

    def _cut_short(self, version: int) -> str | None:
        """Why a look stops here (None: it goes on, or a find changed the plan ``version``)."""
        sm = self.pilot.sm
        if sm.plan_version != version:
            return None
        if sm.state in (State.HOLD, State.ABORT) or not self.pilot.healthy():
            return f"cut short: {sm.state.value}"
        return None

    def watch_from(self, view: PlanItem, candidate: Insulator, version: int) -> str | None:
        """Fly to ``view`` (the obstacle map rechecked on the way), settle (a braking, turning
        body's frames box a string badly) and watch ``candidate`` for :func:`look_events` events,
        in vehicle time too (a detector that stops asking must not hold the vehicle here).
        Why the look stopped early (None: watched to the end, or a find)."""
        pilot = self.pilot
        try:
            leg = self.legs.plan([view], counted=False)
        except PlanningError as exc:
            return f"not flown: {exc}"
        for t, _ in leg.fly(lambda: view.yaw):
            note = self._cut_short(version)
            if note is not None or pilot.sm.plan_version != version:
                return note
            if leg.blocked(t):
                return "cut short: the LiDAR sees an obstacle on the way"
        if pilot.sm.plan_version != version:
            return None
        if settle(pilot, view, 0.0) is None:
            return "cut short: abort"
        events0 = self.runner.counts.events
        budget = look_events(self.mission.inspection.confirmations, candidate.observations)
        st = pilot.vehicle.state()
        limit = st.time + self.watch_time(candidate)
        while pilot.sm.plan_version == version and st.time < limit and self.runner.counts.events - events0 < budget:
            st = pilot.tick(view.position, None, view.yaw)
            note = self._cut_short(version)
            if note is not None:
                return note
        return None

    def watch_time(self, candidate: Insulator) -> float:
        """s a view watches ``candidate`` at most once settled: its detection events, and the
        photo settle's timeout for a detector that falls behind."""
        events = look_events(self.mission.inspection.confirmations, candidate.observations)
        return events * max(self.detect_period, CONTROL_PERIOD) + PHOTO_SETTLE_TIMEOUT

    def view_time(self, candidate: Insulator) -> float:
        """s a view stands at most: the settle (PHOTO_SETTLE_TIMEOUT), then the watch."""
        return PHOTO_SETTLE_TIMEOUT + self.watch_time(candidate)

    def wait_for_perception(self, item: PlanItem, arrival: float) -> None:
        """Hover at ``item`` until perception has handed on every frame taken up to ``arrival``,
        at most the pairing window plus PAIRING_WAIT; sooner when the plan changes (a find) or
        the mission holds or aborts. Why: a frame's LiDAR points come up to PAIRING_WAIT s after
        its window (a loaded computer: 1.3-1.5 s at the median against PX4 SITL), and once the
        search is over a find only refines the registry, so a string seen in the last pass's
        last seconds was reported without a photo, or never confirmed."""
        sm = self.pilot.sm
        deadline = arrival + self.runner.pipeline.pairing_window + PAIRING_WAIT + CONTROL_PERIOD
        version = sm.plan_version
        while not self.runner.caught_up(arrival):
            st = self.pilot.tick(item.position, None, item.yaw)
            if sm.plan_version != version or sm.state in (State.HOLD, State.ABORT) or st.time >= deadline:
                return
