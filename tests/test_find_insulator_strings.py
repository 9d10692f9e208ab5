"""find_insulator_strings against the simulator's ground truth, and its handling of bad input.

Truth: the shipped towers A (twelve near-horizontal tension strings, doubled at every arm tip,
with jumpers and conductors collinear with the strings) and B (four vertical suspension
strings), scanned by the simulated Mid-360 along the mission's own exploration path, one frame
every survey period (``helpers.exploration_clouds``): the density one exploration leaves in
the obstacle map, half of it (every other frame), and every frame the LiDAR makes (five times
the map's density: dense clouds join what sparse ones leave apart).

A generated case adds clutter to tower B: smooth cylinders of a string's size, a twin-conductor
bundle and a bird-guard spike.

A found string matches a true one when its centre is within MATCH_RADIUS of the truth's centre
and its axis within MATCH_ANGLE_DEG; each truth takes at most one found string. Tolerances:
every string found and no false find, at every density; centre error within MATCH_RADIUS
(measured: at most 0.15 m); axis within MATCH_ANGLE_DEG (measured under 1 deg).
"""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass

import numpy as np
import pytest
from helpers.exploration_clouds import exploration_cloud

import insulator_rs as ir
from insulator_rs._core import MAX_STRING_POINTS, find_insulator_strings_defaults
from insulator_rs.flight.leg_follower import SURVEY_PERIOD
from insulator_rs.sim.lidar import Mid360
from insulator_rs.sim.scene import ObstacleSpec
from insulator_rs.sim.towers import Tower

MATCH_RADIUS = 0.5  # m
MATCH_ANGLE_DEG = 5.0
DEFAULTS = dict(find_insulator_strings_defaults())


@dataclass(frozen=True)
class Score:
    n_true: int
    found: int
    matched: int
    false: int
    centre_errors: tuple[float, ...]
    axis_errors_deg: tuple[float, ...]

    @property
    def recall(self) -> float:
        return self.matched / self.n_true

    def line(self, case: str) -> str:
        return (f"{case}: recall {self.matched}/{self.n_true}, false {self.false}, centre error "
                f"max {max(self.centre_errors, default=math.nan):.3f} m mean "
                f"{np.mean(self.centre_errors) if self.centre_errors else math.nan:.3f} m, axis error max "
                f"{max(self.axis_errors_deg, default=math.nan):.2f} deg")


def score(tower: Tower, found: list[ir.InsulatorString]) -> Score:
    """Greedy matching, closest pairs first."""
    pairs = []
    for t, truth in enumerate(tower.insulators):
        for f, s in enumerate(found):
            d = float(np.linalg.norm(s.center - truth.center))
            angle = math.degrees(math.acos(min(1.0, abs(float(s.axis @ truth.axis)))))
            if d <= MATCH_RADIUS and angle <= MATCH_ANGLE_DEG:
                pairs.append((d, angle, t, f))
    used_t: set[int] = set()
    used_f: set[int] = set()
    errors, angles = [], []
    for d, angle, t, f in sorted(pairs):
        if t not in used_t and f not in used_f:
            used_t.add(t)
            used_f.add(f)
            errors.append(d)
            angles.append(angle)
    return Score(len(tower.insulators), len(found), len(used_t), len(found) - len(used_f),
                 tuple(errors), tuple(angles))


@pytest.mark.slow
@pytest.mark.parametrize(("frame_stride", "period"), [
    (1, SURVEY_PERIOD), (2, SURVEY_PERIOD), (1, Mid360().frame_period),
], ids=["one exploration", "half of one", "every LiDAR frame of one"])
@pytest.mark.parametrize("name", ["tower_b", "tower_a"])
def test_every_string_of_the_towers_is_found_and_nothing_else(name: str, frame_stride: int,
                                                               period: float) -> None:
    tower, cloud = exploration_cloud(name, frame_stride, period=period)
    found = ir.find_insulator_strings(cloud)
    result = score(tower, found)
    print(result.line(f"{name}, {len(cloud)} points, a frame every {period * frame_stride:g} s"))
    assert result.recall == 1.0, result
    assert result.false == 0, result
    for s in found:
        assert np.linalg.norm(s.axis) == pytest.approx(1.0)
        assert s.score >= DEFAULTS["min_score"]
        assert s.length == pytest.approx(tower.spec.insulators.length, abs=0.35)
        assert s.radius == pytest.approx(tower.spec.insulators.shed_radius, abs=0.03)
    # The kind of string shows in the elevation: tower B hangs vertical, tower A's droop 6 deg.
    want = math.pi / 2 if tower.insulators[0].kind == "suspension" else math.radians(6.0)
    assert all(abs(s.elevation - want) < math.radians(2.0) for s in found), [s.elevation for s in found]


@pytest.mark.slow
def test_float32_and_another_up_axis_give_the_same_strings() -> None:
    """The same scan as float32 and with y as the vertical (``up``) finds the same strings."""
    tower, cloud = exploration_cloud("tower_b")
    want = ir.find_insulator_strings(cloud)
    got32 = ir.find_insulator_strings(cloud.astype(np.float32))
    assert score(tower, got32).matched == len(tower.insulators) and len(got32) == len(want)
    swap = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # z up -> y up
    turned = ir.find_insulator_strings(cloud @ swap.T, up=(0.0, 1.0, 0.0))
    assert len(turned) == len(want)
    for a, b in zip(sorted(want, key=lambda s: tuple(s.center)), sorted(turned, key=lambda s: tuple(swap.T @ s.center))):
        assert np.allclose(swap @ a.center, b.center, atol=0.05)
        assert b.elevation == pytest.approx(a.elevation, abs=0.02)


def test_an_empty_or_flat_cloud_has_no_strings() -> None:
    assert ir.find_insulator_strings(np.empty((0, 3))) == []
    rng = np.random.default_rng(0)
    ground = np.column_stack([rng.uniform(-20, 20, (200_000, 2)), rng.normal(0, 0.02, 200_000)])
    assert ir.find_insulator_strings(ground) == []


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_non_finite_coordinate_is_refused_by_name(bad: float) -> None:
    cloud = np.zeros((10, 3))
    cloud[7, 1] = bad
    with pytest.raises(ValueError, match=r"^points: row 7 is not finite"):
        ir.find_insulator_strings(cloud)


def test_too_many_points_are_refused_at_once() -> None:
    """More than MAX_STRING_POINTS rows: a named error before any work (a zero-stride view, so
    the test holds no gigabytes)."""
    huge = np.broadcast_to(np.zeros((1, 3)), (MAX_STRING_POINTS + 1, 3))
    with pytest.raises(ValueError, match=r"^points: at most 50000000 points"):
        ir.find_insulator_strings(huge)


@pytest.mark.parametrize(("kwargs", "name"), [
    ({"up": (0.0, 0.0, 0.0)}, "up"),
    ({"up": (0.0, math.nan, 1.0)}, "up"),
    ({"voxel_size": 0.0}, "voxel_size"),
    ({"voxel_size": 1.0}, "voxel_size"),
    ({"min_length": -1.0}, "min_length"),
    ({"max_length": 0.1}, "max_length"),
    ({"min_score": math.nan}, "min_score"),
])
def test_bad_tuning_is_refused_by_name(kwargs: dict[str, object], name: str) -> None:
    with pytest.raises(ValueError, match=rf"^{name}:"):
        ir.find_insulator_strings(np.zeros((5, 3)), **kwargs)  # type: ignore[arg-type]


def test_a_cloud_of_the_wrong_shape_or_type_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match="points: expected shape"):
        ir.find_insulator_strings(np.zeros((5, 2)))
    with pytest.raises(TypeError, match="points"):
        ir.find_insulator_strings(np.zeros((5, 3), dtype=np.int64))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"^up: expected 3 numbers, got shape \(2,\)"):
        ir.find_insulator_strings(np.zeros((5, 3)), up=(0.0, 1.0))  # type: ignore[arg-type]
    with pytest.raises(TypeError, match=r"up: expected a float array"):
        ir.find_insulator_strings(np.zeros((5, 3)), up="z")  # type: ignore[arg-type]


def test_the_signature_shows_the_core_defaults() -> None:
    """help() shows the defaults fusion_core uses (the text signature is written by hand)."""
    params = inspect.signature(ir.find_insulator_strings).parameters
    for key, value in DEFAULTS.items():
        assert params[key].default == value, key
    assert params["up"].default == (0.0, 0.0, 1.0)
    assert params["up"].kind is inspect.Parameter.KEYWORD_ONLY


def test_the_result_is_frozen_and_readable() -> None:
    tower, cloud = _one_string_scene()
    (s,) = ir.find_insulator_strings(cloud)
    assert "InsulatorString(center=" in repr(s)
    with pytest.raises(AttributeError):
        s.length = 1.0  # type: ignore[misc]
    with pytest.raises(ValueError):
        s.center[0] = 0.0
    assert np.linalg.norm(s.center - tower) < 0.1


def _one_string_scene() -> tuple[np.ndarray, np.ndarray]:
    """A stack of 19 sheds (0.11/0.077 m at a 0.08 m pitch) along z, its centre at (1, 2, 10),
    seen all round, with 1 cm noise; and that centre."""
    rng = np.random.default_rng(3)
    parts = []
    for k in range(19):
        skirt = 0.11 if k % 2 == 0 else 0.077
        r = rng.uniform(0.03, skirt, 150)
        phi = rng.uniform(0, 2 * np.pi, 150)
        z = 10.0 + 0.72 - 0.08 * k - 0.02 * (r - 0.03) / skirt
        parts.append(np.column_stack([1.0 + r * np.cos(phi), 2.0 + r * np.sin(phi), z]))
    cloud = np.concatenate(parts) + rng.normal(0, 0.005, (19 * 150, 3))
    return np.array([1.0, 2.0, 10.0]), cloud


# Clutter added to tower B's scene: two smooth cylinders of a string's size hanging in clear
# air (what every test but the shed comb would take for a string), a twin-conductor bundle
# below the lower arms, and a bird-guard spike on an arm tip.
SMOOTH_DECOYS = (
    ObstacleSpec("smooth pole, a suspension string's size", (5.6, -1.2, 14.8), (5.6, -1.2, 16.3), 0.1),
    ObstacleSpec("smooth rod, a tension string's size", (-5.0, 1.0, 12.0), (-4.0, 2.7, 12.2), 0.12),
)
CLUTTER = SMOOTH_DECOYS + (
    ObstacleSpec("bundle conductor a", (-20.0, -27.0, 13.0), (20.0, 27.0, 13.0), 0.015),
    ObstacleSpec("bundle conductor b", (-19.64, -27.27, 13.0), (20.36, 26.73, 13.0), 0.015),
    ObstacleSpec("bird guard spike", (3.7, -2.8, 17.2), (3.7, -2.8, 17.9), 0.01),
)


@pytest.mark.slow
def test_clutter_is_not_taken_for_strings_and_the_shed_comb_is_what_tells() -> None:
    """Tower B with CLUTTER, one exploration: every string, no false find. With the shed
    contrast floor off (min_score=0), both smooth decoys come back: they pass every other
    test, so the shed comb is what rejects them (measured scores 2-4; strings 19-50)."""
    tower, cloud = exploration_cloud("tower_b", obstacles=CLUTTER)
    found = ir.find_insulator_strings(cloud)
    result = score(tower, found)
    print(result.line(f"tower_b with clutter, {len(cloud)} points"))
    assert result.recall == 1.0 and result.false == 0, result
    loose = ir.find_insulator_strings(cloud, min_score=0.0)
    for decoy in SMOOTH_DECOYS:
        middle = 0.5 * (np.array(decoy.start) + np.array(decoy.end))
        nearest = min(loose, key=lambda s: float(np.linalg.norm(s.center - middle)))
        assert np.linalg.norm(nearest.center - middle) < MATCH_RADIUS, decoy.name
        assert nearest.score < DEFAULTS["min_score"], (decoy.name, nearest)
