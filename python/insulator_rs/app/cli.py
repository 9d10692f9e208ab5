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


class UserHelpFormatter(argparse.RawDescriptionHelpFormatter):
    """``--help`` for users: descriptions printed as written, and every option that takes a
    value shows its default, unless its help already states one in words (a default of None
    means "not given"; such an option says what happens then)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        help_text = action.help or ""
        takes_value = bool(action.option_strings) and action.nargs != 0
        if not takes_value or "default" in help_text:
            return help_text
        if action.required:
            return f"{help_text} (required)"
        if action.default in (None, argparse.SUPPRESS):
            return help_text
        return f"{help_text} (default: %(default)s)"


def _apply_user_help(parser: argparse.ArgumentParser) -> None:
    """Give every parser of the tree the users' help format; a subcommand without a
    description of its own shows its one-line help as the description."""
    parser.formatter_class = UserHelpFormatter
    for action in parser._actions:
        if not isinstance(action, argparse._SubParsersAction):
            continue
        helps = {choice.dest: choice.help for choice in action._choices_actions}
        for name, subparser in action.choices.items():
            if subparser.description is None and helps.get(name):
                subparser.description = f"{name}: {helps[name]}."
            _apply_user_help(subparser)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="insulator-rs",
        description="Insulator detection, localization and single-flight inspection for UAVs. "
                    "Run 'insulator-rs COMMAND --help' for a command's options.",
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
    _apply_user_help(parser)
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
