"""``insulator-rs eval localization``: the paper's Tables I and II, reproduced in simulation.

For each tower (A: twelve strain insulators; B: four suspension insulators) and
each standoff w (m, the UAV's horizontal distance from the insulator across the
line), the study draws localization events. One event:

1. picks a target insulator and places the UAV on its side of the line, w
   metres out, with a random offset along the line (``--along-spread``) and in
   height (``--height-range``), the camera facing the tower (yaw jitter);
2. flies it along the line at ``--speed`` m/s and takes a detection event every
   ``--event-interval`` s: a camera image (ground-truth boxes from the rendered
   instance-id image, so occlusion is right) degraded by the detector
   stand-in, and the latest Mid-360 frame (sim.lidar, moving vehicle, so the
   frame carries its motion distortion, as a real one does);
3. hands each image, its box, the LiDAR points of that instant (the scans ending at the
   image and one scan later, as the flight loop pairs them) and the (noisy) odometry poses
   at 20 Hz to the flight's own :class:`~insulator_rs.perception.pipeline.PerceptionPipeline`,
   one per method, until it attempts a localization (its third detection event holding
   LiDAR points): pairing, deskewing, culling, accumulation, ``ir.localize`` and the
   plausibility gates are the code that flies, with the mission file's insulator length;
4. compares the centre it returns (in W) with the ground truth; no result (a
   ``LocalizationError``, too few points, a size that does not fit the box, or a shape the
   false-find filter refuses) is a failure.

Errors: centre distance (m), its horizontal and vertical components (m), and
the angle between the estimated and true axes (degrees). The command prints
the table (mean ± std) beside the paper's numbers, writes ``events.csv``,
``summary.csv`` and ``table.txt`` and saves ``errors.png`` into ``--out``.
``--eps``/``--min-points``/``--tau``/``--ransac-threshold`` override
``ir.localize``'s tuning for sensitivity runs.

Boxes are associated with the target by the ground-truth instance id the
stand-in carries (the registry's association is not what this study measures).
``purity`` is the share of the accumulated points inside the target's true envelope
(shed radius + 8 cm around its axis, within its length + 8 cm).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from insulator_rs import bounds
from insulator_rs.perception.localization_method import LocalizationMethod
from insulator_rs.mission.config import load_mission
from insulator_rs.evaluation.study_scenes import StudyRig, event_poses, localization_errors, localize_event
from insulator_rs.report.folder import parse_out_folder

if TYPE_CHECKING:
    from insulator_rs.sim.detector_standin import DetectorStandin
    from insulator_rs.sim.towers import InsulatorTruth, Tower

_M = LocalizationMethod  # short, for the tables below
# the tables' order: the paper's rows (RANSAC first), then the bounded method
METHODS: tuple[LocalizationMethod, ...] = (_M.RANSAC, _M.DBSCAN_RANSAC, _M.DBSCAN, _M.DBSCAN_PCA,
                                               _M.BOUNDED)
TOWERS: dict[str, str] = {"A": "tower_a", "B": "tower_b"}
MISSIONS_DIR = Path(__file__).resolve().parents[1] / "missions"
# The paper's cells: tower A at 8, 9, 10 m, tower B at 8, 9 m.
DEFAULT_STANDOFFS: dict[str, tuple[float, ...]] = {"A": (8.0, 9.0, 10.0), "B": (8.0, 9.0)}
# Paper Tables I and II: mean ± std of the centre error (m), 150 measurements per cell.
PAPER: dict[tuple[str, float], dict[LocalizationMethod, tuple[float, float]]] = {
    ("A", 8.0): {_M.RANSAC: (0.40, 0.20), _M.DBSCAN_RANSAC: (0.35, 0.17), _M.DBSCAN: (0.74, 0.57),
                 _M.DBSCAN_PCA: (0.79, 0.65)},
    ("A", 9.0): {_M.RANSAC: (0.40, 0.24), _M.DBSCAN_RANSAC: (0.37, 0.23), _M.DBSCAN: (0.66, 0.47),
                 _M.DBSCAN_PCA: (0.60, 0.57)},
    ("A", 10.0): {_M.RANSAC: (0.43, 0.30), _M.DBSCAN_RANSAC: (0.38, 0.22), _M.DBSCAN: (0.50, 0.33),
                  _M.DBSCAN_PCA: (0.40, 0.35)},
    ("B", 8.0): {_M.RANSAC: (0.39, 0.24), _M.DBSCAN_RANSAC: (0.34, 0.20), _M.DBSCAN: (0.32, 0.21),
                 _M.DBSCAN_PCA: (0.33, 0.21)},
    ("B", 9.0): {_M.RANSAC: (0.43, 0.21), _M.DBSCAN_RANSAC: (0.36, 0.23), _M.DBSCAN: (0.41, 0.25),
                 _M.DBSCAN_PCA: (0.41, 0.26)},
}


@dataclass(frozen=True)
class StudyConfig:
    """Everything that defines a run (units: m, s, degrees)."""

    towers: tuple[str, ...] = ("A", "B")
    standoffs: dict[str, tuple[float, ...]] = field(default_factory=lambda: dict(DEFAULT_STANDOFFS))
    events: int = 150
    methods: tuple[LocalizationMethod, ...] = METHODS
    seed: int = 0
    speed: float = 1.0
    event_interval: float = 0.2
    along_spread: float = 2.0
    height_range: tuple[float, float] = (-1.0, 0.5)
    yaw_jitter_deg: float = 5.0
    odom_position_noise: float = 0.02
    odom_yaw_noise_deg: float = 0.2
    box_jitter: float = 0.03
    miss_rate: float = 0.0
    false_positives: float = 0.0
    # Overrides of ir.localize's tuning (None: the library default).
    localize_params: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class EventResult:
    """One localization event with one method (errors in m and degrees; NaN when it failed).

    error_axial: centre error along the true axis (m, the part the clutter at an insulator's
    ends pulls); n_points: points that determined the centre; n_input: accumulated culled points;
    purity: share of those inside the target's true envelope (ground truth of the simulator).
    """

    tower: str
    standoff: float
    event: int
    insulator: int
    method: str
    ok: bool
    error: float
    error_horizontal: float
    error_vertical: float
    angle_deg: float
    error_axial: float
    n_points: int
    n_input: int
    purity: float
    # "ok", "failed" (no usable cloud), "implausible" (size does not fit the box) or "not an
    # insulator" (the false-find filter: shape)
    outcome: str = "ok"


def cell_inputs(tower_key: str, cfg: StudyConfig, seed: int) -> tuple[np.random.Generator, DetectorStandin, float]:
    """A cell's random stream, its detector stand-in (both from ``seed``) and the tower's
    mission insulator length (m)."""
    from insulator_rs.sim.detector_standin import DetectorStandin

    detector = DetectorStandin(jitter=cfg.box_jitter, miss_rate=cfg.miss_rate,
                               false_positives=cfg.false_positives, seed=seed)
    length = load_mission(MISSIONS_DIR / f"{TOWERS[tower_key]}.toml").inspection.insulator_length
    return np.random.default_rng(seed), detector, length


def run_cell(rig: StudyRig, tower_key: str, standoff: float, cfg: StudyConfig,
             progress: Callable[[int, int], None] | None = None) -> list[EventResult]:
    """``cfg.events`` localization events at one standoff; one result per event and method."""
    seed = cfg.seed * 1000 + int(round(standoff * 10)) + (0 if tower_key == "A" else 500)
    rng, detector, length = cell_inputs(tower_key, cfg, seed)
    insulators = rig.tower.insulators
    results: list[EventResult] = []

    def attempt(event: int) -> bool:
        target = insulators[int(rng.integers(len(insulators)))]
        trajectory, times = event_poses(rig.tower, target, standoff, rng, cfg)
        got = localize_event(rig, target, trajectory, times, detector, rng, cfg, length)
        if got is None:
            return False
        for method in cfg.methods:
            loc, outcome, n_input, purity = got[(method, "full")]
            if loc is None:
                results.append(EventResult(tower_key, standoff, event, target.instance_id, method,
                                           False, math.nan, math.nan, math.nan, math.nan,
                                           math.nan, 0, n_input, purity, outcome))
                continue
            err, err_h, err_v, ang, err_axial = localization_errors(loc.center, loc.axis, target)
            results.append(EventResult(tower_key, standoff, event, target.instance_id, method, True,
                                       err, err_h, err_v, ang, err_axial, loc.n_points, n_input, purity))
        if progress is not None:
            progress(event + 1, cfg.events)
        return True

    draw_events(cfg.events, f"tower {tower_key}, w = {standoff} m", attempt)
    return results


def draw_events(count: int, what: str, attempt: Callable[[int], bool]) -> None:
    """Call ``attempt(event)`` until ``count`` calls returned True (a usable event, numbered from
    0); RuntimeError after 20 attempts per event and 20 more."""
    event = attempts = 0
    while event < count:
        attempts += 1
        if attempts > 20 * count + 20:
            raise RuntimeError(f"{what}: only {event} usable events in {attempts - 1} attempts (the target "
                               "is rarely seen by both sensors)")
        if attempt(event):
            event += 1


@dataclass(frozen=True)
class CellSummary:
    """Statistics of one (tower, standoff, method) cell over its successful events."""

    tower: str
    standoff: float
    method: str
    n: int
    failures: int
    mean: float
    std: float
    median: float
    horizontal_mean: float
    horizontal_std: float
    vertical_mean: float
    vertical_std: float
    angle_mean_deg: float
    angle_std_deg: float
    axial_mean: float
    mean_points: float
    mean_purity: float
    paper_mean: float
    paper_std: float


def summarize(results: Sequence[EventResult]) -> list[CellSummary]:
    """One :class:`CellSummary` per (tower, standoff, method), in table order."""
    keys: list[tuple[str, float, str]] = []
    for r in results:
        key = (r.tower, r.standoff, r.method)
        if key not in keys:
            keys.append(key)
    out = []
    for tower, standoff, method in keys:
        rows = [r for r in results if (r.tower, r.standoff, r.method) == (tower, standoff, method)]
        ok = [r for r in rows if r.ok]

        def stat(attr: str) -> tuple[float, float]:
            v = np.array([getattr(r, attr) for r in ok], dtype=np.float64)
            if len(v) == 0:
                return math.nan, math.nan
            return float(v.mean()), float(v.std(ddof=1)) if len(v) > 1 else 0.0

        e = stat("error")
        h = stat("error_horizontal")
        v = stat("error_vertical")
        a = stat("angle_deg")
        paper = PAPER.get((tower, standoff), {}).get(LocalizationMethod.parse(method), (math.nan, math.nan))
        out.append(CellSummary(
            tower=tower, standoff=standoff, method=method, n=len(ok), failures=len(rows) - len(ok),
            mean=e[0], std=e[1],
            median=float(np.median([r.error for r in ok])) if ok else math.nan,
            horizontal_mean=h[0], horizontal_std=h[1], vertical_mean=v[0], vertical_std=v[1],
            angle_mean_deg=a[0], angle_std_deg=a[1], axial_mean=stat("error_axial")[0],
            mean_points=float(np.mean([r.n_input for r in rows])) if rows else math.nan,
            mean_purity=float(np.mean([r.purity for r in rows])) if rows else math.nan,
            paper_mean=paper[0], paper_std=paper[1]))
    return out


def format_table(summary: Sequence[CellSummary]) -> str:
    """The paper-style tables: one per tower, methods as rows, standoffs as columns."""
    lines: list[str] = []
    for tower in dict.fromkeys(s.tower for s in summary):
        cells = [s for s in summary if s.tower == tower]
        standoffs = list(dict.fromkeys(s.standoff for s in cells))
        methods = list(dict.fromkeys(s.method for s in cells))
        lines.append(f"Tower {tower}: centre error [m], mean ± std (paper) | horizontal | "
                     "vertical [m] | axis [deg] | failures/events")
        header = f"{'method':<16}" + "".join(f"| w = {w:g} m{'':<44}" for w in standoffs)
        lines.append(header)
        for m in methods:
            row = f"{LocalizationMethod.parse(m).label:<16}"
            for w in standoffs:
                c = next(s for s in cells if s.standoff == w and s.method == m)
                paper = f"({c.paper_mean:.2f} ± {c.paper_std:.2f})" if math.isfinite(c.paper_mean) else ""
                row += (f"| {c.mean:.2f} ± {c.std:.2f} {paper:<14} {c.horizontal_mean:.2f} "
                        f"{c.vertical_mean:.2f} {c.angle_mean_deg:4.1f}° {c.failures}/{c.n + c.failures} ")
            lines.append(row)
        lines.append("")
    return "\n".join(lines)


def write_csv(path: Path, rows: Sequence[object]) -> None:
    """Write dataclass rows as CSV (header from the first row's fields)."""
    dicts = [asdict(r) for r in rows]  # type: ignore[call-overload]
    with path.open("w", newline="") as f:
        if not dicts:
            return
        writer = csv.DictWriter(f, fieldnames=list(dicts[0]))
        writer.writeheader()
        writer.writerows(dicts)


def write_study(out: Path, name: str, rows: Sequence[object], table: str) -> int:
    """A study's ``name``.csv (rows) and ``name``.txt (table) into ``out``; prints the table, returns 0."""
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / f"{name}.csv", rows)
    (out / f"{name}.txt").write_text(table + "\n")
    print(table)
    return 0


def plot_errors(results: Sequence[EventResult], path: Path) -> None:
    """Box plots of the centre error per method, grouped by standoff, one panel per tower, log
    scale (the paper's mean marked as a black tick). Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    towers = list(dict.fromkeys(r.tower for r in results))
    methods = list(dict.fromkeys(r.method for r in results))
    colors = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple"]
    fig, axes = plt.subplots(1, len(towers), figsize=(6 * len(towers), 4.5), squeeze=False)
    for ax, tower in zip(axes[0], towers):
        standoffs = sorted({r.standoff for r in results if r.tower == tower})
        width = 0.8 / max(1, len(methods))
        for mi, m in enumerate(methods):
            data, pos, paper = [], [], []
            for wi, w in enumerate(standoffs):
                errs = [r.error for r in results if r.tower == tower and r.standoff == w
                        and r.method == m and r.ok]
                data.append(errs if errs else [math.nan])
                x = wi + (mi - (len(methods) - 1) / 2) * width
                pos.append(x)
                paper.append(PAPER.get((tower, w), {}).get(LocalizationMethod.parse(m), (math.nan, math.nan))[0])
            bp = ax.boxplot(data, positions=pos, widths=width * 0.85, patch_artist=True,
                            showfliers=True, flierprops={"markersize": 2})
            for patch in bp["boxes"]:
                patch.set_facecolor(colors[mi % len(colors)])
                patch.set_alpha(0.6)
            ax.plot(pos, paper, linestyle="none", marker="_", markersize=14, color="black",
                    label="paper mean" if mi == 0 else None)
            ax.plot([], [], color=colors[mi % len(colors)], linewidth=8, alpha=0.6,
                    label=LocalizationMethod.parse(m).label)
        ax.set_xticks(range(len(standoffs)), [f"w = {w:g} m" for w in standoffs])
        # Log scale: the boxes (a few dm) and the gross failures (metres, another object
        # taken for the insulator) both stay readable.
        ax.set_yscale("log")
        ax.set_ylabel("centre error [m] (log scale)")
        ax.set_title(f"Tower {tower}")
        ax.grid(axis="y", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _progress_printer(label: str) -> Callable[[int, int], None]:
    """Progress on stderr: one updating line on a terminal, a line per 10 % otherwise (logs)."""
    start = time.monotonic()
    tty = sys.stderr.isatty()

    def show(done: int, total: int) -> None:
        step = max(1, total // 10)
        if not tty and done % step and done != total:
            return
        elapsed = time.monotonic() - start
        eta = elapsed / done * (total - done) if done else math.nan
        text = f"  {label}: {done}/{total} events, {elapsed:.0f} s elapsed, ETA {eta:.0f} s"
        if tty:
            print("\r" + text, end="\n" if done == total else "", file=sys.stderr, flush=True)
        else:
            print(text, file=sys.stderr, flush=True)

    return show


def run_study(cfg: StudyConfig, out: Path | None,
              progress: bool = True) -> tuple[list[EventResult], list[CellSummary]]:
    """Run every cell of ``cfg``; write CSVs and the plot into ``out`` when given."""
    results: list[EventResult] = []
    for tower_key in cfg.towers:
        rig = StudyRig(TOWERS[tower_key], cfg, seed=cfg.seed)
        for w in cfg.standoffs[tower_key]:
            show = _progress_printer(f"tower {tower_key}, w = {w:g} m") if progress else None
            results.extend(run_cell(rig, tower_key, w, cfg, show))
    summary = summarize(results)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        write_csv(out / "events.csv", results)
        write_csv(out / "summary.csv", summary)
        plot_errors(results, out / "errors.png")
        (out / "table.txt").write_text(format_table(summary))
    return results, summary


def _positive_float(text: str) -> float:
    v = float(text)
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return v


def _positive_int(text: str) -> int:
    v = int(text)
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {text}")
    return v


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``insulator-rs eval localization``."""
    parser.add_argument("--towers", nargs="+", choices=sorted(TOWERS), default=["A", "B"],
                        help="towers to evaluate (default: A B)")
    parser.add_argument("--standoffs", nargs="+", type=_positive_float, default=None,
                        help="standoffs w in m for every tower (default: the paper's, "
                             "A: 8 9 10, B: 8 9)")
    parser.add_argument("--events", type=_positive_int, default=150,
                        help="localization events per cell (default 150, as the paper)")
    parser.add_argument("--methods", nargs="+", type=LocalizationMethod, choices=list(LocalizationMethod),
                        default=list(METHODS), help="localization methods to run (default: all)")
    parser.add_argument("--seed", type=bounds.option("--seed"), default=0,
                        help="random seed of the study (integer, 0 to 2^32-1)")
    parser.add_argument("--box-jitter", type=float, default=StudyConfig.box_jitter,
                        help="detector stand-in: box edge noise, fraction of the box size")
    parser.add_argument("--miss-rate", type=float, default=StudyConfig.miss_rate,
                        help="detector stand-in: probability that a visible insulator gets no box")
    parser.add_argument("--false-positives", type=bounds.option("--false-positives"),
                        default=StudyConfig.false_positives,
                        help="detector stand-in: mean false boxes per image")
    parser.add_argument("--odom-noise", type=float, default=StudyConfig.odom_position_noise,
                        help="odometry position noise, m (1 sigma)")
    parser.add_argument("--eps", type=_positive_float, default=None,
                        help="DBSCAN radius in m (default: ir.localize's)")
    parser.add_argument("--min-points", type=_positive_int, default=None,
                        help="DBSCAN core size (default: ir.localize's)")
    parser.add_argument("--tau", type=_positive_float, default=None,
                        help="distance to the line in m for the centre (default: ir.localize's)")
    parser.add_argument("--ransac-threshold", type=_positive_float, default=None,
                        help="RANSAC inlier distance in m (default: ir.localize's)")
    parser.add_argument("--out", type=parse_out_folder, default=Path("results/localization"),
                        help="folder for events.csv, summary.csv, errors.png")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")


def run(args: argparse.Namespace) -> int:
    """Entry point of ``insulator-rs eval localization``; prints the table, returns 0."""
    standoffs = ({k: tuple(args.standoffs) for k in TOWERS} if args.standoffs
                 else dict(DEFAULT_STANDOFFS))
    if not 0.0 <= args.miss_rate < 1.0:
        raise ValueError(f"--miss-rate: must be within [0, 1), got {args.miss_rate}")
    for name in ("box_jitter", "false_positives", "odom_noise"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v >= 0.0):
            raise ValueError(f"--{name.replace('_', '-')}: must be a finite number >= 0, got {v}")
    cfg = StudyConfig(towers=tuple(args.towers), standoffs=standoffs, events=args.events,
                      methods=tuple(args.methods), seed=args.seed, box_jitter=args.box_jitter,
                      miss_rate=args.miss_rate, false_positives=args.false_positives,
                      odom_position_noise=args.odom_noise,
                      localize_params={k: getattr(args, k) for k in
                                       ("eps", "min_points", "tau", "ransac_threshold")
                                       if getattr(args, k) is not None})
    start = time.monotonic()
    _, summary = run_study(cfg, args.out, progress=not args.quiet)
    print(format_table(summary))
    print(f"{cfg.events} events per cell, {time.monotonic() - start:.0f} s; wrote "
          f"{args.out / 'events.csv'}, {args.out / 'summary.csv'}, {args.out / 'errors.png'}")
    return 0
