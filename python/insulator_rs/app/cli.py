"""The ``insulator-rs`` command: one entry point, one module per subcommand.

Each subcommand module exposes ``register(subparsers)`` which adds its parser
and sets ``func`` to a callable taking the parsed namespace and returning an
exit code. Modules are imported lazily so that ``insulator-rs --help`` stays fast
and a heavy optional dependency (Ultralytics) is only loaded by its command.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from types import ModuleType

# (subcommand, module that registers it)
SUBCOMMANDS: tuple[tuple[str, str], ...] = (
    ("inspect", "insulator_rs.app.inspect_command"),
    ("eval", "insulator_rs.app.eval_command"),
    ("detect", "insulator_rs.app.detect_command"),
    ("train", "insulator_rs.app.train_command"),
    ("dataset", "insulator_rs.app.dataset_command"),
    ("replay", "insulator_rs.app.replay_command"),
    ("report", "insulator_rs.app.report_command"),
    ("calibrate", "insulator_rs.app.calibrate_command"),
)

# Subcommands of an optional part -> the extra that provides their dependencies. Without
# it (a plain ``pip install``, as on a Jetson) the subcommand is still listed, and running
# it says what to install instead of every command failing on the missing import.
EXTRAS: dict[str, str] = {"replay": "bags", "calibrate": "bags"}


def import_optional(module_name: str) -> ModuleType | None:
    """Import a subcommand module; None only if that module itself is absent (an
    optional part not installed). A missing dependency inside it still raises."""
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name != module_name:
            raise
        return None


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="insulator-rs",
        description="Insulator detection, localization and single-flight inspection for UAVs.",
    )
    subparsers = parser.add_subparsers(dest="command", required=True)
    for name, module_name in SUBCOMMANDS:
        try:
            module = import_optional(module_name)
        except ModuleNotFoundError as exc:
            if name not in EXTRAS:
                raise
            _register_missing_extra(subparsers, name, EXTRAS[name], exc)
            continue
        if module is not None:
            module.register(subparsers)
    return parser


def _register_missing_extra(subparsers: argparse._SubParsersAction[argparse.ArgumentParser], name: str, extra: str,
                            exc: ModuleNotFoundError) -> None:
    message = f"error: {name} needs the {extra} extra (pip install 'insulator_rs[{extra}]'): {exc}"
    parser = subparsers.add_parser(name, help=f"(not installed: needs the {extra} extra)", add_help=False)
    parser.add_argument("rest", nargs=argparse.REMAINDER)

    def run(_args: argparse.Namespace) -> int:
        print(message, file=sys.stderr)
        return 2

    parser.set_defaults(func=run)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
