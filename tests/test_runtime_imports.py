"""Every import of the package is declared in pyproject.toml, where a user will find it.

A plain ``pip install insulator_rs`` (no extras), as on a Jetson, must run the main job:
CI's pmm.py (now planning/pmm.py) once imported scipy, declared only by the test extra, and nobody
noticed because every CI venv held ``[test]``. Two checks:

* ``test_every_import_is_declared`` (static, any venv): every import statement in
  ``python/insulator_rs`` (module level or inside a function, except under
  ``TYPE_CHECKING``) of a module outside the standard library names a distribution
  of ``[project] dependencies``; modules of an optional part (``OPTIONAL`` below:
  the recordings of the ``bags`` extra (replay, calibrate), the offline training tools of ``train``,
  COCO scoring, the GStreamer camera of ``gstreamer``) may use their extra's distributions instead, and nothing else.
* ``python tests/test_runtime_imports.py`` (dynamic, run by .ci/run and
  scripts/test-aarch64.sh in a venv holding the wheel alone): imports every
  onboard module, i.e. every module not in ``OPTIONAL``. The in-suite
  ``test_onboard_modules_import`` does the same in the test venv (weaker: the extras
  are installed there).
"""

from __future__ import annotations

import ast
import importlib
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "python" / "insulator_rs"

# Import name -> distribution, for the names that differ or come in through another
# declared distribution (torch and torchvision are Ultralytics' own requirements).
DISTRIBUTION = {
    "cv2": "opencv-python-headless",
    "gi": "PyGObject",
    "yaml": "PyYAML",
    "serial": "pyserial",
    "rerun": "rerun-sdk",
    "mcap_ros2": "mcap-ros2-support",
    "torch": "ultralytics",
    "torchvision": "ultralytics",
}

# Module (relative to the package, "/"-separated prefix) -> the extra that provides its
# third-party imports. Everything else is onboard and may use [project] dependencies only.
OPTIONAL = {
    "recording/": "bags",  # record flights, read bags (rosbags, mcap)
    "replay/": "bags",  # replay flights, fleet re-processing (Ray), progress bars, Rerun logs
    "app/replay_command.py": "bags",
    "app/calibrate_command.py": "bags",  # calibrate time-offset reads a recorded flight
    "evaluation/fault_matrix.py": "bags",  # the fault matrix reads each cell's recording back
    "drivers/gstreamer_camera.py": "gstreamer",  # GStreamer pipelines through PyGObject (--camera gst:...)
    "detection/train.py": "train",  # the offline training tools (Ultralytics + PyTorch)
    "app/train_command.py": "train",
    "detection/warm_start.py": "train",
    "detection/uav_augment.py": "train",
    # the FP16 export reads and writes ONNX graphs (onnx) on a workstation or the Jetson, not in
    # flight; the detector's TensorRT cache options in the same module need nothing beyond the runtime
    "detection/jetson_export.py": "train",
    # `insulator-rs detect eval`: COCO scores on a labelled split, a workstation tool;
    # pycocotools is declared by the test extra only.
    "detection/evaluate.py": "test",
}


# The standard library of every supported Python: tomllib is stdlib from 3.11 on (_toml.py
# imports it there, and the declared tomli backport below).
STDLIB = frozenset(sys.stdlib_module_names) | {"tomllib"}


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _requirement_name(req: str) -> str:
    match = re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)", req)
    assert match, req
    return _norm(match.group(1))


def _pyproject() -> dict:
    from insulator_rs._toml import tomllib

    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def declared() -> tuple[set[str], dict[str, set[str]]]:
    """([project] dependencies, {extra: its distributions, self-references expanded})."""
    project = _pyproject()["project"]
    runtime = {_requirement_name(r) for r in project["dependencies"]}
    raw = project.get("optional-dependencies", {})
    extras: dict[str, set[str]] = {}
    for extra, reqs in raw.items():
        names: set[str] = set()
        for req in reqs:
            inner = re.match(r"\s*insulator[-_]rs\[([^\]]+)\]", req)
            if inner:
                for sub in inner.group(1).split(","):
                    names |= {_requirement_name(r) for r in raw[sub.strip()]}
            else:
                names.add(_requirement_name(req))
        extras[extra] = names
    return runtime, extras


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def third_party_imports(path: Path) -> dict[str, int]:
    """{top-level module: first line} of the non-stdlib, non-package imports of one file."""
    found: dict[str, int] = {}

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.orelse:
                visit(child)
            return
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        for name in names:
            top = name.split(".")[0]
            if top not in STDLIB and top not in ("insulator_rs", "__future__"):
                found.setdefault(top, node.lineno)  # type: ignore[attr-defined]
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(ast.parse(path.read_text(encoding="utf-8"), filename=str(path)))
    return found


def _extra_of(relative: str) -> str | None:
    for prefix, extra in OPTIONAL.items():
        if relative == prefix or (prefix.endswith("/") and relative.startswith(prefix)):
            return extra
    return None


def _relative(path: Path) -> str:
    return path.relative_to(PACKAGE).as_posix()


def onboard_modules() -> list[str]:
    """Dotted names of the package's modules outside ``OPTIONAL``."""
    out = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name == "__main__.py":  # a package's command line (python -m): running it is not importing it
            continue
        if _extra_of(_relative(path)) is None:
            parts = ("insulator_rs", *path.relative_to(PACKAGE).with_suffix("").parts)
            out.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return out


def test_every_import_is_declared() -> None:
    runtime, extras = declared()
    problems = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = _relative(path)
        extra = _extra_of(rel)
        allowed = runtime | (extras[extra] if extra else set())
        for module, line in third_party_imports(path).items():
            dist = _norm(DISTRIBUTION.get(module, module))
            if dist not in allowed:
                where = f"the {extra} extra or [project] dependencies" if extra else "[project] dependencies"
                problems.append(f"{rel}:{line}: imports {module} ({dist}), not in {where}")
    assert not problems, "\n".join(problems)


def test_optional_table_names_real_files_and_extras() -> None:
    _, extras = declared()
    for prefix, extra in OPTIONAL.items():
        assert extra in extras, f"{prefix}: no extra {extra!r} in pyproject.toml"
        assert (PACKAGE / prefix).exists(), f"{prefix}: no such module or folder"


def _module_level_imports(path: Path) -> dict[str, int]:
    """{imported module: line} of what loads the moment one file is imported: its module-level
    imports, in if/try blocks too, not in functions or under ``TYPE_CHECKING``."""
    found: dict[str, int] = {}

    def visit(body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, ast.If):
                if not _is_type_checking(node.test):
                    visit(node.body)
                visit(node.orelse)
            elif isinstance(node, ast.Try):
                visit(node.body)
                for handler in node.handlers:
                    visit(handler.body)
                visit(node.orelse)
                visit(node.finalbody)
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    found.setdefault(alias.name, node.lineno)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                found.setdefault(node.module, node.lineno)
                if node.module.split(".")[0] == "insulator_rs":
                    # ``from insulator_rs.recording import types``: the name may be a module,
                    # which loads too (sim/flight_assembly.py reached rosbags this way)
                    for alias in node.names:
                        found.setdefault(f"{node.module}.{alias.name}", node.lineno)

    visit(ast.parse(path.read_text(encoding="utf-8"), filename=str(path)).body)
    return found


def _module_file(dotted: str) -> Path | None:
    parts = dotted.split(".")[1:]
    if not parts:
        return PACKAGE / "__init__.py"
    rel = Path(*parts)
    for candidate in (PACKAGE / rel.with_suffix(".py"), PACKAGE / rel / "__init__.py"):
        if candidate.exists():
            return candidate
    return None


def _loads_on_import(path: Path, seen: dict[Path, set[str]]) -> set[str]:
    """The third-party distributions importing ``path`` loads, through the package's own
    module-level imports (depth first; ``seen`` memoises and breaks cycles)."""
    if path in seen:
        return seen[path]
    seen[path] = set()
    out: set[str] = set()
    for name in _module_level_imports(path):
        top = name.split(".")[0]
        if top == "insulator_rs":
            target = _module_file(name)
            if target is not None:
                out |= _loads_on_import(target, seen)
        elif top not in STDLIB and top != "__future__":
            out.add(_norm(DISTRIBUTION.get(top, top)))
    seen[path] = out
    return out


def test_no_onboard_module_loads_an_extra_on_import() -> None:
    """The transitive half of the rule: app/calibrate_command.py (onboard by the table then)
    imported replay/time_offset.py at module level, which imports the recordings, which import
    rosbags; a plain install's ``insulator-rs`` then failed to start, the main job included."""
    runtime, _ = declared()
    seen: dict[Path, set[str]] = {}
    problems = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if _extra_of(_relative(path)) is None:
            missing = _loads_on_import(path, seen) - runtime
            if missing:
                problems.append(f"{_relative(path)}: importing it loads {sorted(missing)}, "
                                f"not in [project] dependencies")
    assert not problems, "\n".join(problems)


def test_every_optional_subcommand_says_which_extra_it_needs() -> None:
    """A subcommand module of an optional part must be in the command line's EXTRAS, or a
    plain install's ``insulator-rs --help`` (and every other command) fails on its import."""
    from insulator_rs.app import cli

    for name, module_name in cli.SUBCOMMANDS:
        target = _module_file(module_name)
        assert target is not None, module_name
        extra = _extra_of(_relative(target))
        if extra in ("bags", "gstreamer"):  # train's extra is absent by design: import_optional skips it
            assert cli.EXTRAS.get(name) == extra, f"{name}: {module_name} needs the {extra} extra"


def test_the_scan_sees_function_level_imports() -> None:
    """pmm's scipy and geoexport's simplekml are the kind of import this must catch."""
    assert "scipy" in third_party_imports(PACKAGE / "planning" / "pmm.py")
    assert "simplekml" in third_party_imports(PACKAGE / "report" / "geoexport.py")


def test_onboard_modules_import() -> None:
    for name in onboard_modules():
        importlib.import_module(name)


def main() -> int:
    """Import every onboard module; for a venv that holds the wheel and nothing else."""
    failed = 0
    modules = onboard_modules()
    for name in modules:
        try:
            importlib.import_module(name)
        except Exception as exc:  # report every failing module, then fail
            failed += 1
            print(f"FAIL {name}: {type(exc).__name__}: {exc}", file=sys.stderr)
    print(f"runtime imports: {len(modules) - failed} of {len(modules)} onboard modules import "
          f"(Python {sys.version.split()[0]}, {sys.platform})")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
