"""The main job on the small scene (tower B's design cut to a 12 m body with one cross-arm, two
insulators), as CI flies it from the wheel alone on each CPU, and the comparison of two such
flights.

    python scripts/small_scene_flight.py fly OUT        # writes OUT/scene, flies, report in OUT/report
    python scripts/small_scene_flight.py compare A B    # two OUT folders: the same insulators?

Why the small scene and the stand-in detector: under qemu-aarch64 this flight takes about 5
minutes; tower B's takes over an hour, and the network (~16 s a frame under emulation, twice a
second of flight) many more. The network's aarch64 output is checked frame by frame against the
x86-64 reference instead (tests/test_detection_cross_arch.py).

The comparison's reference is the other CPU's flight of the same wheel version: the same
number of insulators found and inspected, the same photos, and every insulator's centre within
POSITION_TOL_M of its counterpart (measured: 1e-11 m apart between x86-64 and qemu-aarch64;
the flight is deterministic, so only the CPUs' floating-point rounding differs, and a
difference that moved an insulator by centimetres would mean the CPUs decided differently).
Exit status 0 when they agree, 1 when they differ, 2 on a missing or unreadable report.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

POSITION_TOL_M = 0.01
# detection twice a second at a fifth of the camera's size, photos at a fifth: as the
# mission tests fly this scene (tests/test_mission_inspect.py ARGS)
FLIGHT_ARGS = ["--detect-period", "0.5", "--detect-scale", "0.2", "--photo-scale", "0.2", "--quiet",
               "--detector", "standin"]


def fly(out: Path) -> int:
    import insulator_rs
    from insulator_rs.app.cli import main
    from insulator_rs.evaluation.fault_matrix import small_scene

    package = Path(insulator_rs.__file__).parent
    scene, mission = small_scene(out / "scene", package / "scenes", package / "missions")
    return main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out / "report"),
                 *FLIGHT_ARGS])


class ReportUnreadable(Exception):
    """A flight's summary.json is missing, unreadable or not an inspect summary."""


def _summary(folder: Path) -> dict:
    path = folder / "report" / "summary.json"
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ReportUnreadable(f"{path}: {exc}") from None
    if not isinstance(summary, dict) or not isinstance(summary.get("insulators"), list):
        raise ReportUnreadable(f"{path}: not an inspect summary (no insulators list)")
    return summary


def compare(a: Path, b: Path) -> list[str]:
    """What differs between the two flights' reports (empty: they agree)."""
    sa, sb = _summary(a), _summary(b)
    problems = []
    for key in ("status", "insulators_found", "insulators_inspected"):
        if sa.get(key) != sb.get(key):
            problems.append(f"{key}: {sa.get(key)!r} in {a}, {sb.get(key)!r} in {b}")
    if [p.get("file") for p in sa.get("photos", [])] != [p.get("file") for p in sb.get("photos", [])]:
        problems.append("the photos taken differ")
    if len(sa["insulators"]) != len(sb["insulators"]):
        problems.append(f"{len(sa['insulators'])} insulators in {a}, {len(sb['insulators'])} in {b}")
        return problems
    worst = 0.0
    for ia, ib in zip(sa["insulators"], sb["insulators"]):
        d = sum((float(x) - float(y)) ** 2 for x, y in zip(ia["center"], ib["center"])) ** 0.5
        worst = max(worst, d)
        if d > POSITION_TOL_M:
            problems.append(f"insulator {ia.get('id')}: centres {d:.4f} m apart (tolerance {POSITION_TOL_M} m)")
    print(f"compare: {len(sa['insulators'])} insulators, centres at most {worst:.2e} m apart")
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p_fly = sub.add_parser("fly", help="fly the small scene; the report goes to OUT/report")
    p_fly.add_argument("out", type=Path)
    p_cmp = sub.add_parser("compare", help="compare two flights' reports")
    p_cmp.add_argument("a", type=Path)
    p_cmp.add_argument("b", type=Path)
    args = parser.parse_args(argv)
    if args.command == "fly":
        return fly(args.out)
    try:
        problems = compare(args.a, args.b)
    except ReportUnreadable as exc:
        print(f"compare: {exc}", file=sys.stderr)
        return 2
    for p in problems:
        print(f"compare: {p}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
