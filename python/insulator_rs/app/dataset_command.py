"""``insulator-rs dataset``: render a YOLO-format training set of tower images."""

from __future__ import annotations

import argparse
import math

from insulator_rs.report.folder import parse_out_folder


def _positive_int(text: str) -> int:
    v = int(text)
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {text}")
    return v


def _fraction(text: str) -> float:
    v = float(text)
    if not (math.isfinite(v) and 0.0 <= v <= 1.0):
        raise argparse.ArgumentTypeError(f"must be within [0, 1], got {text}")
    return v


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``dataset`` subcommand to the ``insulator-rs`` parser."""
    parser = subparsers.add_parser(
        "dataset", help="render images of simulated towers with YOLO labels and a data.yaml")
    parser.add_argument("--scenes", nargs="+", default=["tower_a", "tower_b"],
                        help="scene TOML files or built-in scene names (default: tower_a tower_b)")
    parser.add_argument("--images", type=_positive_int, default=1500,
                        help="number of images in total, spread over the scenes (default 1500, "
                             "as the paper's simulation dataset)")
    parser.add_argument("--split", nargs=3, type=_fraction, default=[0.8, 0.1, 0.1],
                        metavar=("TRAIN", "VAL", "TEST"), help="split fractions (default 0.8 0.1 0.1)")
    parser.add_argument("--out", type=parse_out_folder, required=True, help="output folder")
    parser.add_argument("--width", type=_positive_int, default=None,
                        help="image width in px (default: the simulated camera's)")
    parser.add_argument("--height", type=_positive_int, default=None,
                        help="image height in px (default: the simulated camera's)")
    parser.add_argument("--min-visible-pixels", type=_positive_int, default=30,
                        help="leave out insulators with fewer visible pixels (default 30)")
    parser.add_argument("--seed", type=int, default=0, help="random seed of the renders (integer)")
    parser.add_argument("--steel-views", action="store_true",
                        help="render hard negatives instead: views aimed at the tower's steel (peak, arms, legs) "
                             "from where the inspection path flies, at the flight's 320x240 detection size unless "
                             "--width/--height say otherwise, with every visible insulator in truth.json "
                             "(see sim/steel_views.py; `detect eval --steel-views` counts a model's false boxes)")
    parser.add_argument("--quiet", action="store_true", help="no progress line")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Render the dataset and print where it went."""
    from insulator_rs.sim.dataset import write_dataset

    if args.width is not None and args.height is None or args.height is not None and args.width is None:
        raise ValueError("--width/--height: give both or neither")
    if args.steel_views:
        return _run_steel_views(args)
    summary = write_dataset(
        scenes=args.scenes, out=args.out, n_images=args.images, split=tuple(args.split),
        image_size=(args.width, args.height) if args.width is not None else None,
        min_visible_pixels=args.min_visible_pixels, seed=args.seed, progress=not args.quiet)
    counts = ", ".join(f"{k} {v}" for k, v in summary.images.items())
    print(f"wrote {sum(summary.images.values())} images ({counts}), {summary.boxes} boxes, "
          f"{summary.empty_images} without insulators; {summary.data_yaml}")
    return 0


def _run_steel_views(args: argparse.Namespace) -> int:
    """Render the steel views (hard negatives) and print where they went."""
    import sys

    from insulator_rs.sim.steel_views import FLIGHT_DETECTION_SIZE, write_steel_views

    def progress(done: int, total: int) -> None:
        if not args.quiet and (done % max(1, total // 20) == 0 or done == total):
            print(f"  {done}/{total} steel views", file=sys.stderr, flush=True)

    summary = write_steel_views(
        scenes=args.scenes, out=args.out, n_images=args.images, split=tuple(args.split),
        image_size=(args.width, args.height) if args.width is not None else FLIGHT_DETECTION_SIZE,
        seed=args.seed, progress=progress)
    counts = ", ".join(f"{k} {v}" for k, v in summary.images.items())
    print(f"wrote {sum(summary.images.values())} steel views ({counts}), {summary.boxes} insulator boxes "
          f"labelled, {summary.empty_images} with none labelled; {summary.data_yaml}")
    return 0
