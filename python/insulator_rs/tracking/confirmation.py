"""The track-confirmation rule: how many localizations make an insulator, and when one is made.

A real string is localized at every detection event that sees it (tens per pass), while a
box that once caught the lattice behind a far-side string gives a one-off localization on
the steel: a record is *confirmed* (reported, inspected) once :data:`CONFIRMATIONS`
localizations have fallen within its gate, the M-of-N confirmation of multi-target tracking
with N unbounded. The registry applies the rule, the mission file sets the count and the
second look asks how many localizations a candidate still lacks: all read it here. The
allowed range is the validation layer's (:data:`insulator_rs.bounds.MISSION`), read here too.
"""

from __future__ import annotations

from insulator_rs import bounds

# A string in view is localized at every detection event (1 Hz) for tens of seconds: 33-250
# localizations per flight on towers A and B. The lattice members that pass every shape check
# and have a confident box gather 3 each, in a few frames of one pass: with 3 confirmations one
# was registered now and then. The small scene's short flight still confirms both strings at 4.
#: localizations within the gate before an insulator is registered (the mission's default)
CONFIRMATIONS = 4
#: the allowed counts, with the reason (the mission file's limit)
CONFIRMATIONS_LIMIT = bounds.MISSION["inspection.confirmations"]
#: the fewest: 1 registers an insulator at its first localization, as the paper does
MIN_CONFIRMATIONS = int(CONFIRMATIONS_LIMIT.lo)


def check_confirmations(confirmations: int) -> int:
    """``confirmations`` when it is a whole number within CONFIRMATIONS_LIMIT; ValueError naming it otherwise."""
    if isinstance(confirmations, bool) or not isinstance(confirmations, int):
        raise ValueError(f"confirmations: must be a whole number, got {confirmations!r}")
    problem = CONFIRMATIONS_LIMIT.problem(confirmations)
    if problem is not None:
        raise ValueError(f"confirmations: {problem}")
    return confirmations


#: how many times the confirmations a record needs while the LiDAR's geometry contradicts it (no
#: string-like structure where it was localized, in a map that covers the place: flight/lidar_cue.py).
#: A real string is localized tens of times a flight (33-250 on towers A and B), so a string the
#: geometry wrongly doubts is confirmed a few localizations later; the steel a box caught now and
#: then gathers 3 in one pass and stays a candidate.
HELD_FACTOR = 2


def is_confirmed(observations: int, confirmations: int, *, held: bool = False) -> bool:
    """Whether a record localized ``observations`` times is confirmed at ``confirmations``
    (``held``: contradicted by the LiDAR's geometry, HELD_FACTOR times as many)."""
    return observations >= confirmations * (HELD_FACTOR if held else 1)


def localizations_missing(observations: int, confirmations: int, *, held: bool = False) -> int:
    """The localizations a record seen ``observations`` times still lacks to be confirmed (0 once
    it is; ``held``: as :func:`is_confirmed`)."""
    return max(confirmations * (HELD_FACTOR if held else 1) - observations, 0)
