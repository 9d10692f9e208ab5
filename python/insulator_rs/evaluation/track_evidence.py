"""Per-track evidence (issue 22 item 4): are the birth rule's BIRTH_SCORE and the registry's
confirmations still right for the shipped network?

Every run's ``summary.json`` lists its perception tracks (``tracks``: each track that gathered
enough boxes for a localization attempt, with its box count, best score, confident boxes,
localizations handed on, held back by the birth rule, refused), and the post-flight scorer's
``score.json`` labels each with its nearest true insulator (``true_insulator``: within the
scorer's match distance). This reads one or more scored report folders and tells, per run and
over all of them:

* **true insulators**: per string (its tracks together, as the registry fuses them) the
  localizations handed on and the best box; the weakest string bounds how high the thresholds
  may go;
* **tracks on something else** (steel, conductors): those whose localizations passed the shape
  and scale gates and so reached the birth rule, their best box and the localizations they
  handed on; the strongest bounds how low the thresholds may go.

Where the LiDAR cue flew (``flight/lidar_cue.py``), each track carries the geometry's word at its
centre (``lidar``): the judgement then counts the false tracks past the gates that the geometry
contradicts (held for more localizations) and the strings it contradicts (which it must not).

The verdict (:func:`judge`) says, for BIRTH_SCORE and for the confirmations, whether every false
track is stopped and every string passes, with the margins on both sides. Change a threshold
only on that evidence (issue 22: "change them only on that evidence").

``python -m insulator_rs.evaluation.track_evidence REPORT_DIR [REPORT_DIR ...] [--json OUT] [--plot PNG]``
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from insulator_rs.flight.lidar_cue import CONTRADICTED
from insulator_rs.tracking.confirmation import CONFIRMATIONS, is_confirmed
from insulator_rs.perception.pipeline import BIRTH_SCORE


@dataclass
class RunEvidence:
    """One scored run: per true insulator (instance id) its localizations and best box; per
    track on something else its localizations, best box and distance from the nearest string."""

    run: str
    strings: dict[int, dict[str, float]] = field(default_factory=dict)
    false_tracks: list[dict[str, Any]] = field(default_factory=list)
    strings_in_scene: int = 0


def read_run(folder: Path) -> RunEvidence:
    """The evidence of one scored report folder (``score.json`` with ``tracks``)."""
    path = Path(folder) / "score.json"
    try:
        score = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: {exc}") from None
    if not isinstance(score, dict) or not isinstance(score.get("tracks"), list):
        raise ValueError(f"{path}: no per-track list (tracks): a report from before tracks were recorded, "
                         f"or not a score.json")
    ev = RunEvidence(run=str(folder), strings_in_scene=int(score.get("insulators_in_scene", 0)))
    for t in score["tracks"]:
        if t.get("true_insulator"):
            s = ev.strings.setdefault(int(t["gt_instance_id"]), {"localizations": 0, "best_score": 0.0, "tracks": 0})
            s["localizations"] += int(t["localizations"])
            s["best_score"] = max(s["best_score"], float(t["best_score"]))
            s["tracks"] += 1
            if "lidar" in t:  # the LiDAR cue flew: does the geometry contradict the string?
                s["lidar_contradicted"] = s.get("lidar_contradicted", 0) + (t["lidar"] == CONTRADICTED)
        else:
            ev.false_tracks.append({"localizations": int(t["localizations"]), "best_score": float(t["best_score"]),
                                    "boxes": int(t["boxes"]), "held_before_birth": int(t["held_before_birth"]),
                                    "distance_m": t.get("distance_m"), "lidar": t.get("lidar")})
    return ev


def judge(runs: list[RunEvidence], birth_score: float = BIRTH_SCORE,
          confirmations: int = CONFIRMATIONS) -> dict[str, Any]:
    """Whether the thresholds stop every false track and pass every string, with the margins."""
    strings = [s for r in runs for s in r.strings.values()]
    false = [t for r in runs for t in r.false_tracks]
    # a false track's localization reaches the birth rule only past the shape and scale gates;
    # it reaches the registry only with a confident box, and is confirmed only with
    # `confirmations` localizations handed on
    at_birth = [t for t in false if t["localizations"] + t["held_before_birth"] > 0]
    born = [t for t in at_birth if t["best_score"] >= birth_score]
    confirmed = [t for t in born if is_confirmed(int(t["localizations"]), confirmations)]
    weakest = min(strings, key=lambda s: (s["localizations"], s["best_score"])) if strings else None
    out: dict[str, Any] = {
        "birth_score": birth_score, "confirmations": confirmations,
        "runs": len(runs), "strings_in_scenes": sum(r.strings_in_scene for r in runs),
        "strings_tracked": len(strings), "false_tracks": len(false),
        "false_tracks_born": len(born), "false_tracks_confirmed": len(confirmed),
        "strings_best_score_min": min((s["best_score"] for s in strings), default=None),
        "strings_localizations_min": min((s["localizations"] for s in strings), default=None),
        "weakest_string": weakest,
        "false_tracks_past_the_gates": len(at_birth),
        "false_past_the_gates_best_score_max": max((t["best_score"] for t in at_birth), default=None),
        "false_born_localizations_max": max((t["localizations"] for t in born), default=None),
    }
    strings_pass = bool(strings) and all(s["best_score"] >= birth_score and is_confirmed(int(s["localizations"]), confirmations)
                                         for s in strings)
    with_lidar = [t for t in at_birth if t.get("lidar") is not None]
    if with_lidar or any("lidar_contradicted" in st for st in strings):
        # the second cue: a false track past the gates that the geometry contradicts is held for
        # more localizations; a string the geometry contradicts would be held too (never lost)
        out["lidar"] = {"false_past_the_gates_with_lidar": len(with_lidar),
                        "false_past_the_gates_contradicted": sum(1 for t in with_lidar if t["lidar"] == CONTRADICTED),
                        "strings_with_a_contradicted_track": sum(1 for st in strings if st.get("lidar_contradicted"))}
    out["verdict"] = {
        "every_false_track_stopped": not confirmed,
        "every_tracked_string_passes": strings_pass,
        # can the threshold alone tell them apart (every false track below every string)?
        "birth_score_separates": _separates(out["false_past_the_gates_best_score_max"], out["strings_best_score_min"]),
        "confirmations_separate": _separates(out["false_born_localizations_max"], out["strings_localizations_min"]),
        "birth_score_room": _room(out["false_past_the_gates_best_score_max"], out["strings_best_score_min"]),
        "confirmations_room": _room(out["false_born_localizations_max"], out["strings_localizations_min"]),
    }
    return out


def _separates(false_max: float | None, true_min: float | None) -> bool:
    return true_min is not None and (false_max is None or false_max < true_min)


def _room(false_max: float | None, true_min: float | None) -> str:
    """The open interval a threshold may sit in: above every false track, at or below every string."""
    lo = "-" if false_max is None else f"{false_max:g}"
    hi = "-" if true_min is None else f"{true_min:g}"
    return f"above {lo}, up to {hi}"


def table(runs: list[RunEvidence], birth_score: float = BIRTH_SCORE) -> str:
    """A markdown table, one row per run (false tracks "born": with a box of at least ``birth_score``)."""
    lines = ["| run | strings tracked / in scene | string localizations min / median | string best box min "
             "| false tracks / past the gates / born | false past the gates: best box max | false born: localizations max |",
             "|---|---|---|---|---|---|---|"]
    for r in runs:
        locs = sorted(s["localizations"] for s in r.strings.values())
        best = min((s["best_score"] for s in r.strings.values()), default=float("nan"))
        gated = [t for t in r.false_tracks if t["localizations"] + t["held_before_birth"] > 0]
        born = [t for t in gated if t["best_score"] >= birth_score]
        fbest = max((t["best_score"] for t in gated), default=float("nan"))
        floc = max((t["localizations"] for t in born), default=0)
        med = locs[len(locs) // 2] if locs else 0
        lines.append(f"| {Path(r.run).name} | {len(r.strings)} / {r.strings_in_scene} | "
                     f"{locs[0] if locs else 0} / {med} | {best:.2f} | {len(r.false_tracks)} / {len(gated)} / {len(born)} | "
                     f"{fbest:.2f} | {floc} |")
    return "\n".join(lines)


def plot(runs: list[RunEvidence], path: Path, birth_score: float = BIRTH_SCORE,
         confirmations: int = CONFIRMATIONS) -> Path:
    """Each string (its tracks together) and each false track: best box against localizations
    handed on, with the two thresholds; false tracks the shape and scale gates stopped apart."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    strings = [s for r in runs for s in r.strings.values()]
    false = [t for r in runs for t in r.false_tracks]
    gated = [t for t in false if t["localizations"] + t["held_before_birth"] > 0]
    stopped = [t for t in false if t["localizations"] + t["held_before_birth"] == 0]
    jitter = np.random.default_rng(0)  # spread the many false tracks at 0 localizations
    ax.scatter([t["best_score"] for t in stopped], 0.5 + 0.2 * jitter.random(len(stopped)), s=14, c="0.6",
               label=f"false track, stopped by the shape/scale gates ({len(stopped)})")
    ax.scatter([t["best_score"] for t in gated], [t["localizations"] + 0.8 for t in gated], s=24, c="tab:red",
               marker="x", label=f"false track past the gates ({len(gated)})")
    ax.scatter([s["best_score"] for s in strings], [s["localizations"] for s in strings], s=24, c="tab:blue",
               label=f"true string, its tracks together ({len(strings)})")
    ax.axvline(birth_score, color="k", ls="--", lw=1)
    ax.axhline(confirmations, color="k", ls=":", lw=1)
    ax.text(birth_score, 300, f" BIRTH_SCORE {birth_score:g}", fontsize=8, va="top")
    ax.text(0.02, confirmations * 1.08, f"{confirmations} confirmations", fontsize=8, transform=ax.get_yaxis_transform())
    ax.set_yscale("log")
    ax.set_ylim(0.4, 400)
    ax.set_xlim(0.0, 1.0)
    ax.set_xlabel("best detection score of the track's boxes")
    ax.set_ylabel("localizations handed on (false: +0.8; stopped: ~0.5)")
    ax.set_title(f"per-track evidence, {len(runs)} runs: " + ", ".join(Path(r.run).name for r in runs), fontsize=9)
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="per-track evidence of scored runs: BIRTH_SCORE and the "
                                                 "confirmations against what strings and false tracks gathered")
    parser.add_argument("reports", nargs="+", type=Path, help="report folders, each with a score.json")
    parser.add_argument("--json", type=Path, help="write the runs and the verdict here")
    parser.add_argument("--plot", type=Path, help="write the per-track scatter (PNG) here")
    parser.add_argument("--birth-score", type=float, default=BIRTH_SCORE, help="the birth rule's threshold to judge")
    parser.add_argument("--confirmations", type=int, default=CONFIRMATIONS, help="the confirmations to judge")
    args = parser.parse_args(argv)
    try:
        runs = [read_run(f) for f in args.reports]
    except ValueError as exc:
        print(f"track_evidence: {exc}", file=sys.stderr)
        return 2
    verdict = judge(runs, args.birth_score, args.confirmations)
    print(table(runs, args.birth_score))
    print(json.dumps(verdict, indent=1))
    if args.plot is not None:
        plot(runs, args.plot, args.birth_score, args.confirmations)
    if args.json is not None:
        from insulator_rs.report.jsonfile import write_json
        write_json(args.json, {"runs": [asdict(r) for r in runs], "judgement": verdict})
    return 0


if __name__ == "__main__":
    sys.exit(main())
