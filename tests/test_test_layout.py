"""The test suite's own layout rule (docs/guide/testing.md): shared helpers live in
``tests/helpers/``, and a test module imports from there, never from another test module.

Importing from a test module ties one test file to another's internals, runs that module's
imports and module-level code even when only the importer is run, and hands over its fixtures
by accident (a fixture imported into a module becomes a fixture of that module). Every
``import`` statement in ``tests/`` (at any depth, function bodies included) is read with
``ast``, not run.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parent
TEST_MODULE_PREFIX = "test_"


def imported_test_modules(source: str) -> list[tuple[int, str]]:
    """(line, module) of every import of a ``test_*`` module in ``source``."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module is not None:
            names = [node.module]
        else:
            continue
        found += [(node.lineno, name) for name in names
                  if name.split(".")[0].startswith(TEST_MODULE_PREFIX)]
    return sorted(found)


def python_files() -> list[Path]:
    """The test modules, conftest.py and the helpers."""
    return sorted([*TESTS.glob("*.py"), *(TESTS / "helpers").glob("*.py")])


def test_no_module_of_the_suite_imports_a_test_module() -> None:
    offenders = [f"{path.relative_to(TESTS.parent)}:{line}: imports {module}"
                 for path in python_files()
                 for line, module in imported_test_modules(path.read_text(encoding="utf-8"))]
    assert not offenders, ("move what is shared into tests/helpers/ and import it from there:\n"
                           + "\n".join(offenders))


def test_the_check_sees_every_form_of_import() -> None:
    source = """
import test_a
import numpy, test_b.sub as b
from test_c import x
from helpers.flights import ARGS
from . import test_relative

def f():
    from test_d import y
"""
    assert imported_test_modules(source) == [(2, "test_a"), (3, "test_b.sub"), (4, "test_c"), (9, "test_d")]
    assert imported_test_modules("import numpy\nfrom helpers.px4_sitl import sitl_folder\n") == []


def test_the_suite_collects_without_pytest_xdist() -> None:
    """The aarch64 stage runs its test files under qemu with plain pytest (no pytest-xdist): the
    conftest's scheduler hook must be optional there (an unknown hook stops collection)."""
    done = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:xdist", "-p", "no:cacheprovider", "-q",
                           "--collect-only", str(TESTS / "test_test_layout.py")],
                          capture_output=True, text=True, cwd=TESTS.parent, timeout=120)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
