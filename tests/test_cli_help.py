"""``insulator-rs ... --help`` is written for users.

Every subcommand's help (and every sub-subcommand's: ``detect run``, ``eval localization`` ...)
is rendered and checked: no docstring markup (``:mod:``, ``:class:``, ``:func:``, double
backticks), and every option that takes a value states its default, and, where the default is
a number, its unit.
"""

from __future__ import annotations

import argparse
import re

import pytest

from insulator_rs.app import cli

MARKUP = re.compile(r":(mod|class|func|meth|attr):|``")
# A number's unit, or what it counts, in words: the help of a numeric option must name one.
UNIT = re.compile(
    r"(\b(m|mm|s|ms|m/s|m/s\^?2|Hz|px|pixels?|deg|degrees|rad|ppm|fraction|times|integer|count|"
    r"number|hours?|minutes?|seconds?|metres?|meters?|epochs?|events?|images?|views?|frames?|"
    r"threads?|workers?|batch|boxes|scenes?|tiles?|shards?|photos?|flights?|retakes?|points?|"
    r"insulators?|confirmations?|port|IoU|score|confidence|probability|ratio|scale|factor|percent)\b"
    r"|%|°|m/s²|\bx\b|×)", re.I)


def all_parsers() -> list[tuple[str, argparse.ArgumentParser]]:
    """(command line, parser) for the top level and every subcommand, depth first."""
    found: list[tuple[str, argparse.ArgumentParser]] = []

    def walk(prefix: str, parser: argparse.ArgumentParser) -> None:
        found.append((prefix, parser))
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(f"{prefix} {name}", sub)

    walk("insulator-rs", cli.build_parser())
    return found


PARSERS = all_parsers()


def takes_value(action: argparse.Action) -> bool:
    return bool(action.option_strings) and action.nargs != 0 and not isinstance(action, argparse._HelpAction)


def test_every_subcommand_is_checked() -> None:
    names = {name for name, _ in PARSERS}
    for command, _ in cli.SUBCOMMANDS:
        assert f"insulator-rs {command}" in names
    assert "insulator-rs detect run" in names and "insulator-rs eval localization" in names


@pytest.mark.parametrize(("name", "parser"), PARSERS, ids=[name for name, _ in PARSERS])
def test_help_has_no_docstring_markup(name: str, parser: argparse.ArgumentParser) -> None:
    text = parser.format_help()
    found = sorted({m.group(0) for m in MARKUP.finditer(text)})
    assert not found, f"{name} --help shows docstring markup {found}:\n{text}"
    assert parser.description, f"{name} --help has no description"


@pytest.mark.parametrize(("name", "parser"), PARSERS, ids=[name for name, _ in PARSERS])
def test_every_option_states_its_default_and_unit(name: str, parser: argparse.ArgumentParser) -> None:
    formatter = parser._get_formatter()
    problems = []
    for action in parser._actions:
        if not takes_value(action):
            continue
        shown = formatter._expand_help(action) if action.help else ""
        option = "/".join(action.option_strings)
        if "default" not in shown and "(required)" not in shown:
            problems.append(f"{option}: no default stated: {shown!r}")
        numeric = isinstance(action.default, (int, float)) and not isinstance(action.default, bool)
        if numeric and not UNIT.search(shown):
            problems.append(f"{option}: a number without its unit: {shown!r}")
    assert not problems, f"{name} --help:\n  " + "\n  ".join(problems)


def test_a_bad_option_is_caught() -> None:
    """The checks can fail: an option without help, and a description with markup."""
    parser = argparse.ArgumentParser(description="see :mod:`x`", formatter_class=cli.UserHelpFormatter)
    parser.add_argument("--speed", type=float, default=None, help="how fast")
    parser.add_argument("--gain", type=float, default=2.0, help="the gain")
    with pytest.raises(AssertionError, match="markup"):
        test_help_has_no_docstring_markup("t", parser)
    with pytest.raises(AssertionError) as caught:
        test_every_option_states_its_default_and_unit("t", parser)
    assert "--speed: no default stated" in str(caught.value)
    assert "--gain: a number without its unit" in str(caught.value)


def test_a_default_is_shown_by_the_formatter() -> None:
    parser = argparse.ArgumentParser(formatter_class=cli.UserHelpFormatter)
    parser.add_argument("--period", type=float, default=1.5, help="s between events")
    assert "(default: 1.5)" in parser.format_help()


def test_main_help_runs(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exited:
        cli.main(["inspect", "--help"])
    assert exited.value.code == 0
    assert "--seed" in capsys.readouterr().out
