"""The dependency rules of ARCHITECTURE.md ("## Dependency rules"), checked against the source.

* Every import of the package's own modules, module-level and inside functions, is read with
  ``ast`` and checked against the row of the table that rules the importing module.
* No import circle between modules (function-level imports included).
* ``mission/`` holds no perception: none of its modules is a perception module, and none calls
  the localization kernels of the compiled core.
* The same checks, on a synthetic source tree that breaks a rule and has a circle, fail.
* At run time, importing every onboard module in a fresh interpreter loads no
  ``insulator_rs.sim`` module (the walk covers a new module without editing this test).
"""

from __future__ import annotations

import ast
import json
import os
import pkgutil
import re
import subprocess
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import pytest

import insulator_rs

PACKAGE_DIR = Path(insulator_rs.__file__).resolve().parent
PYTHON_DIR = PACKAGE_DIR.parent
ARCHITECTURE = Path(__file__).resolve().parents[1] / "ARCHITECTURE.md"
ROOT = "insulator_rs"


# -- reading the source ----------------------------------------------------------------------


def module_files(package_dir: Path, root: str = ROOT) -> dict[str, Path]:
    """Dotted module name -> file, for every .py file under ``package_dir``, and the stub of
    each compiled module (``_core.pyi``: its imports are the stub's)."""
    out = {}
    paths = sorted(package_dir.rglob("*.py"))
    paths += [p for p in sorted(package_dir.rglob("*.pyi")) if not p.with_suffix(".py").exists()]
    for path in paths:
        parts = [root, *path.relative_to(package_dir).with_suffix("").parts]
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def imported_modules(name: str, path: Path, modules: set[str]) -> set[str]:
    """The package's modules that ``name`` imports anywhere in its file (in functions, under
    ``TYPE_CHECKING`` and in ``try`` blocks too). ``from a import b`` names the module ``a.b``
    when there is one, else ``a``."""
    is_package = path.name == "__init__.py"
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_package else name.split(".")[:-1]
                base = base[:len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            subs = [f"{target}.{alias.name}" for alias in node.names if f"{target}.{alias.name}" in modules]
            found.update(subs)
            if len(subs) < len(node.names):
                found.add(target)
    # the nearest module of the package for each name (``import insulator_rs.x.y`` names x.y)
    out = set()
    for target in found:
        while target and target not in modules:
            target = target.rpartition(".")[0]
        if target and target != name:
            out.add(target)
    return out


def import_graph(package_dir: Path, root: str = ROOT) -> dict[str, set[str]]:
    files = module_files(package_dir, root)
    names = set(files)
    return {name: imported_modules(name, path, names) for name, path in files.items()}


# -- reading the table -----------------------------------------------------------------------


@dataclass(frozen=True)
class Rule:
    """One row: the modules it rules (tokens) and what they may import."""

    members: tuple[str, ...]
    allowed: tuple[str, ...]  # tokens; "core", "*"
    minus: tuple[str, ...]  # with "*": the tokens excepted
    line: str


def _tokens(cell: str) -> list[str]:
    return re.findall(r"`([^`]+)`", cell)


def parse_rules(markdown: str) -> list[Rule]:
    """The rows of the table under "## Dependency rules"."""
    section = markdown.split("## Dependency rules", 1)[1]
    section = re.split(r"\n## ", section, maxsplit=1)[0]
    rules = []
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 2 or not line.lstrip().startswith("|") or set(cells[0]) <= {"-", " "}:
            continue
        if cells[0] == "module":
            continue
        members = _tokens(cells[0].split(":", 1)[1] if cells[0].startswith("core:") else cells[0])
        allowed_cell = cells[1]
        if " minus " in allowed_cell:
            head, tail = allowed_cell.split(" minus ", 1)
            allowed, minus = _tokens(head), _tokens(tail)
        else:
            allowed, minus = _tokens(allowed_cell), []
        assert members and allowed, f"ARCHITECTURE.md: a row names no module or no import: {line!r}"
        rules.append(Rule(tuple(members), tuple(allowed), tuple(minus), line))
    assert rules, "ARCHITECTURE.md: no dependency table under '## Dependency rules'"
    return rules


def _dotted(token: str, root: str) -> tuple[str, bool]:
    """(dotted name, is a package prefix) of a table token: ``ports/`` -> insulator_rs.ports."""
    if token == root:
        return root, False
    name = token.rstrip("/").removesuffix(".py").replace("/", ".")
    return f"{root}.{name}", token.endswith("/")


def matches(token: str, module: str, root: str = ROOT) -> int:
    """How specifically ``token`` names ``module``: 0 not at all, more is more specific."""
    name, is_package = _dotted(token, root)
    if module == name:
        return 2 * name.count(".") + 2
    if is_package and module.startswith(name + "."):
        return 2 * name.count(".") + 1
    return 0


class Rules:
    def __init__(self, rules: list[Rule], root: str = ROOT) -> None:
        self.rows = rules
        self.root = root
        self.core = rules[0].members

    def row_of(self, module: str) -> Rule | None:
        best: tuple[int, int, Rule] | None = None
        for i, rule in enumerate(self.rows):
            score = max(matches(t, module, self.root) for t in rule.members)
            # a tie (``ports/`` is in the core row and has its own): the later row rules
            if score and (best is None or (score, i) >= best[:2]):
                best = (score, i, rule)
        return None if best is None else best[2]

    def _named(self, tokens: Iterable[str], module: str) -> bool:
        for t in tokens:
            if t == "core":
                if any(matches(c, module, self.root) for c in self.core):
                    return True
            elif t == "*" or matches(t, module, self.root):
                return True
        return False

    def allows(self, importer: str, imported: str) -> bool:
        rule = self.row_of(importer)
        assert rule is not None, f"{importer}: no row of ARCHITECTURE.md's dependency table rules it"
        if imported.startswith(importer + "."):
            return True  # a package's __init__ importing its own modules
        package = importer if importer == self.root else importer.rpartition(".")[0]
        own = self.row_of(package) is rule and (imported == package or imported.startswith(package + "."))
        if own and package != self.root:
            return True  # its own package
        if self._named(rule.minus, imported):
            return False
        return self._named(rule.allowed, imported)


def violations(graph: dict[str, set[str]], rules: Rules) -> set[tuple[str, str]]:
    return {(a, b) for a, targets in graph.items() for b in targets if not rules.allows(a, b)}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import circles: strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


# -- the package -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return import_graph(PACKAGE_DIR)


@pytest.fixture(scope="module")
def rules() -> Rules:
    return Rules(parse_rules(ARCHITECTURE.read_text(encoding="utf-8")))


def test_the_table_has_every_row_and_rules_every_module(graph: dict[str, set[str]], rules: Rules) -> None:
    named = {t for r in rules.rows for t in r.members}
    for package in ("ports/", "perception/", "tracking/", "planning/", "mission/", "flight/", "report/",
                    "recording/", "replay/", "drivers/", "mavlink/", "detection/", "sim/", "evaluation/", "app/"):
        assert package in named, f"ARCHITECTURE.md's table has no row for {package}"
    for module in ("insulator_rs.exceptions", "insulator_rs.poses", "insulator_rs.ports.vehicle"):
        assert rules.row_of(module) is not None
    unruled = sorted(m for m in graph if rules.row_of(m) is None)
    assert not unruled, f"modules no row of ARCHITECTURE.md's table rules: {unruled}"


def test_every_import_follows_its_row(graph: dict[str, set[str]], rules: Rules) -> None:
    found = sorted(violations(graph, rules))
    assert not found, "imports ARCHITECTURE.md's table does not allow:\n" + "\n".join(
        f"  {a} -> {b}   (row: {rules.row_of(a).line.split('|')[1].strip()})" for a, b in found)


def test_no_import_circle(graph: dict[str, set[str]]) -> None:
    circles = cycles(graph)
    assert not circles, f"import circles (function-level imports included): {circles}"


def test_mission_holds_no_perception(graph: dict[str, set[str]]) -> None:
    mission = {m: p for m, p in module_files(PACKAGE_DIR).items() if m.startswith("insulator_rs.mission")}
    perception = {m.rpartition(".")[2] for m in graph if m.startswith("insulator_rs.perception.")}
    assert perception, "perception/ has no module"
    clash = sorted(m for m in mission if m.rpartition(".")[2] in perception)
    assert not clash, f"perception modules in mission/: {clash}"
    kernels = {"localize", "localize_bounded", "localize_defaults", "dbscan", "ransac_line", "pca",
               "points_in_boxes", "deskew", "deskew_points_in_boxes", "project_points"}
    for name, path in mission.items():
        assert not any(m.startswith("insulator_rs.perception") or m == "insulator_rs._core"
                       for m in graph[name]), f"{name} imports perception or the geometry kernels"
        used = {n.attr for n in ast.walk(ast.parse(path.read_text(encoding="utf-8"))) if isinstance(n, ast.Attribute)}
        used |= {n.id for n in ast.walk(ast.parse(path.read_text(encoding="utf-8"))) if isinstance(n, ast.Name)}
        assert not used & kernels, f"{name} calls localization kernels: {sorted(used & kernels)}"


# -- the check can fail ----------------------------------------------------------------------

SYNTHETIC_TABLE = """
## Dependency rules

| module | may import | why |
| --- | --- | --- |
| core: `pkg`, `exceptions`, `ports/` | `core` | shared |
| `planning/` | `core` | plans |
| `mission/` | `core`, `planning/` | behaviour |
| `app/` | `*` | root |

## Next section
"""


def _write(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        path = root / "pkg" / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root / "pkg"


def test_the_checks_fail_on_a_tree_that_breaks_the_rules(tmp_path: Path) -> None:
    """planning imports mission inside a function (not allowed, and a circle with mission's
    module-level import of planning); relative and ``from pkg import module`` forms are read."""
    package = _write(tmp_path, {
        "__init__.py": "",
        "exceptions.py": "class E(Exception):\n    pass\n",
        "ports/__init__.py": "",
        "ports/vehicle.py": "from ..exceptions import E\n",
        "planning/__init__.py": "",
        "planning/path.py": ("from pkg.exceptions import E\n\n"
                             "def plan():\n    from pkg.mission import machine\n    return machine\n"),
        "mission/__init__.py": "",
        "mission/machine.py": "from pkg.planning import path\nfrom . import other\n",
        "mission/other.py": "import pkg.ports.vehicle\n",
        "app/__init__.py": "",
        "app/cli.py": "import pkg.mission.machine\nimport pkg.planning.path\n",
    })
    g = import_graph(package, root="pkg")
    assert g["pkg.planning.path"] == {"pkg.exceptions", "pkg.mission.machine"}  # the function-level one too
    assert g["pkg.mission.machine"] == {"pkg.planning.path", "pkg.mission.other"}
    assert g["pkg.ports.vehicle"] == {"pkg.exceptions"}
    rules = Rules(parse_rules(SYNTHETIC_TABLE), root="pkg")
    assert violations(g, rules) == {("pkg.planning.path", "pkg.mission.machine")}
    assert cycles(g) == [["pkg.mission.machine", "pkg.planning.path"]]
    # without the offending function the tree is clean
    (package / "planning" / "path.py").write_text("from pkg.exceptions import E\n")
    g = import_graph(package, root="pkg")
    assert violations(g, rules) == set() and cycles(g) == []


# -- at run time: no onboard module loads the simulator ---------------------------------------

# What may load the simulator when imported, by module-name prefix: the simulator, the
# evaluation (ground truth, after a flight) and the two composition roots that wire it.
# The other commands reach it only inside the function that needs it.
ALLOWED_TO_USE_SIM = (
    "insulator_rs.sim",
    "insulator_rs.evaluation",
    "insulator_rs.app.inspect_command",
    "insulator_rs.app.cli",
)
# Offline tools with heavy optional dependencies, not part of the flying software.
OFFLINE_TOOLS = ("insulator_rs.detection.train", "insulator_rs.app.train_command")


def onboard_modules() -> list[str]:
    names = []
    for info in pkgutil.walk_packages([str(PACKAGE_DIR)], prefix="insulator_rs."):
        name = info.name
        if name.startswith(ALLOWED_TO_USE_SIM) or name in OFFLINE_TOOLS:
            continue
        names.append(name)
    return sorted(names)


def test_the_walk_covers_every_onboard_layer() -> None:
    names = set(onboard_modules())
    for required in ("insulator_rs._core", "insulator_rs.ports.vehicle", "insulator_rs.ports.sensors",
                     "insulator_rs.exceptions", "insulator_rs.rig", "insulator_rs.poses",
                     "insulator_rs.flight.loop", "insulator_rs.ports.detector",
                     "insulator_rs.perception.pipeline", "insulator_rs.mission.state_machine",
                     "insulator_rs.mavlink.client", "insulator_rs.mavlink.frames",
                     "insulator_rs.detection.detector", "insulator_rs.replay.run",
                     "insulator_rs.recording.reader", "insulator_rs.tracking.registry",
                     "insulator_rs.planning.minsnap"):
        assert required in names, required


def test_no_onboard_module_imports_the_simulator() -> None:
    modules = onboard_modules()
    code = (
        "import importlib, json, sys\n"
        f"for name in {modules!r}:\n"
        "    importlib.import_module(name)\n"
        "print(json.dumps(sorted(m for m in sys.modules if m == 'insulator_rs.sim' "
        "or m.startswith('insulator_rs.sim.'))))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(PYTHON_DIR)})
    assert done.returncode == 0, done.stderr
    loaded = json.loads(done.stdout.strip().splitlines()[-1])
    assert loaded == [], f"onboard modules loaded the simulator: {loaded}"


def test_the_check_would_see_a_simulator_import() -> None:
    """The same probe, on a module that does import the simulator, reports it (the test can fail)."""
    code = ("import sys, insulator_rs.app.inspect_command\n"
            "print(any(m.startswith('insulator_rs.sim') for m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(PYTHON_DIR)})
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "True"
