"""ARCHITECTURE.md's layout tree ("## Layout") against the repository.

The tree is the project's one map of its files: every package (directory) and module of
``python/insulator_rs``, every Rust module of a crate and every binding file in ``src/`` must
have a line, and every line must name something that exists. Each line reads ``name  what it
holds`` (two spaces or more between them), indented two spaces per level, so adding a module is
adding one line under its package.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ARCHITECTURE = REPO / "ARCHITECTURE.md"
PACKAGE = Path("python") / "insulator_rs"
INDENT = 2

# Files that are a package's or a crate's root, not a module of their own: the directory's line
# stands for them.
ROOT_FILES = {"__init__.py", "mod.rs"}
# Build outputs and caches that live beside the sources but are not part of them.
IGNORED_DIRS = {"__pycache__"}


def layout_block(text: str) -> list[str]:
    """The lines of the first fenced block under the '## Layout' heading."""
    match = re.search(r"^## Layout\n(.*?)^```\n(.*?)^```", text, flags=re.S | re.M)
    if match is None:
        raise AssertionError("ARCHITECTURE.md: no fenced tree under '## Layout'")
    return [line for line in match.group(2).splitlines() if line.strip()]


def parse_tree(lines: list[str]) -> set[str]:
    """Repository-relative paths named by the tree ('dir/' for a directory)."""
    paths: set[str] = set()
    stack: list[str] = []
    for number, line in enumerate(lines, start=1):
        indent = len(line) - len(line.lstrip(" "))
        if indent % INDENT:
            raise AssertionError(f"ARCHITECTURE.md layout line {number}: indent {indent} is not a multiple "
                                 f"of {INDENT}: {line!r}")
        level = indent // INDENT
        if level > len(stack):
            raise AssertionError(f"ARCHITECTURE.md layout line {number}: indented under no directory: {line!r}")
        name = re.split(r" {2,}", line.strip(), maxsplit=1)[0]
        if " " in name:
            raise AssertionError(f"ARCHITECTURE.md layout line {number}: the name and its description need two "
                                 f"spaces between them: {line!r}")
        del stack[level:]
        path = "".join(stack) + name
        paths.add(path)
        if name.endswith("/"):
            stack.append(name)
    return paths


def tree_paths() -> set[str]:
    return parse_tree(layout_block(ARCHITECTURE.read_text(encoding="utf-8")))


def source_paths() -> set[str]:
    """What the tree must hold: python/insulator_rs's directories and .py modules, each crate's
    src/ directories and .rs modules, and the binding crate's src/*.rs."""
    wanted: set[str] = set()

    def walk(root: Path, suffix: str) -> None:
        for path in sorted(root.rglob("*")):
            relative = path.relative_to(REPO)
            if any(part in IGNORED_DIRS for part in relative.parts):
                continue
            if path.is_dir():
                wanted.add(relative.as_posix() + "/")
            elif path.suffix == suffix and path.name not in ROOT_FILES:
                wanted.add(relative.as_posix())

    wanted.add(PACKAGE.as_posix() + "/")
    walk(REPO / PACKAGE, ".py")
    for crate in sorted((REPO / "crates").iterdir()):
        if (crate / "src").is_dir():
            wanted.update({f"crates/{crate.name}/", f"crates/{crate.name}/src/"})
            walk(crate / "src", ".rs")
    wanted.add("src/")
    walk(REPO / "src", ".rs")
    return wanted


def test_every_package_and_module_has_a_line() -> None:
    missing = sorted(source_paths() - tree_paths())
    assert not missing, ("missing from ARCHITECTURE.md's layout tree (add one 'name  what it holds' line each "
                         "under its directory):\n  " + "\n  ".join(missing))


def test_every_line_names_something_that_exists() -> None:
    stale = sorted(path for path in tree_paths() if not (REPO / path.rstrip("/")).exists()
                   or path.endswith("/") != (REPO / path.rstrip("/")).is_dir())
    assert not stale, "ARCHITECTURE.md's layout tree names what is not in the repository:\n  " + "\n  ".join(stale)


def test_the_parser_reads_nesting_and_refuses_a_bad_line() -> None:
    assert parse_tree(["a/  the a", "  b.py  a module", "  c/", "    d.rs  deep", "e.toml  top"]) == {
        "a/", "a/b.py", "a/c/", "a/c/d.rs", "e.toml"}
    with pytest.raises(AssertionError, match="two spaces"):
        parse_tree(["a/", "  b.py a module with one space"])
    with pytest.raises(AssertionError, match="indent"):
        parse_tree(["a/", "   b.py  odd indent"])


def test_a_missing_module_is_reported() -> None:
    """The check can fail: drop one line of the real tree and the module is missing."""
    lines = layout_block(ARCHITECTURE.read_text(encoding="utf-8"))
    without = [line for line in lines if not line.strip().startswith("second_look.py")]
    assert len(without) == len(lines) - 1
    assert "python/insulator_rs/flight/second_look.py" in source_paths() - parse_tree(without)
