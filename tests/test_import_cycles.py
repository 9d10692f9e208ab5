"""No import circle: among the modules of ``python/insulator_rs``, nor among the modules of each
Rust crate (``crates/*/src``, the binding crate's ``src``).

A circle means neither module can be read, tested or moved without the other; the fix is a
third module both import (as ``dbscan/cells.rs`` is for ``grid.rs`` and ``sparse.rs``), or one
direction only.

Python: the graph of the package's modules from their ``import`` and ``from ... import``
statements, read with ``ast``, relative imports resolved. ``from a import b`` is an edge to the
module ``a.b`` when there is one, else to ``a``. Imports under ``if TYPE_CHECKING:`` do not
count (they never run: annotations only). **Function-local imports count**: deferring an
import keeps the interpreter from tripping over a circle at load time, but the two modules
still need each other, which is what this test is about.

Rust: a crate's modules are its files (``lib.rs`` the root, ``a.rs`` or ``a/mod.rs`` module
``a``, ``a/b.rs`` module ``a::b``); a module depends on each module named by a ``crate::``,
``super::`` or ``self::`` path in it (``use`` trees with braces included) and on each child
module it names by a relative path, comments and strings left out; a path names the longest
module it starts with. An inline ``mod x { ... }`` (the unit tests) belongs to its file, its
``super`` resolved from inside it. A module's dependence on its own ancestors does not count: a
child module is part of its parent and uses the parent's items by design (``super::*``); a
circle through siblings or cousins does.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "python" / "insulator_rs"
CRATE_SOURCES = sorted(ROOT.glob("crates/*/src")) + [ROOT / "src"]

Graph = dict[str, set[str]]


# -- graph ------------------------------------------------------------------------------------
def circles(graph: Graph) -> list[list[str]]:
    """One circle (a closed path, first module repeated at the end) in each strongly
    connected component of more than one module, or of one module that imports itself."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[set[str]] = []

    def connect(v: str) -> None:  # Tarjan's algorithm; module graphs are shallow
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.add(w)
                if w == v:
                    break
            if len(component) > 1 or v in graph.get(v, ()):
                components.append(component)

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return [_circle_in(graph, component) for component in components]


def _circle_in(graph: Graph, component: set[str]) -> list[str]:
    """A shortest closed path inside ``component`` through its smallest module (breadth first)."""
    start = min(component)
    previous: dict[str, str] = {}
    frontier = [start]
    while frontier:
        following = []
        for v in frontier:
            for w in sorted(graph[v] & component):
                if w == start:
                    path = [v]
                    while path[-1] != start:
                        path.append(previous[path[-1]])
                    return [*reversed(path), start]
                if w not in previous:
                    previous[w] = v
                    following.append(w)
        frontier = following
    raise AssertionError(f"no circle through {start} in {sorted(component)}")


def _named(found: list[list[str]], sep: str = " -> ") -> str:
    return "; ".join(sep.join(c) for c in found)


# -- Python -----------------------------------------------------------------------------------
def python_modules(package: Path) -> dict[str, tuple[Path, bool]]:
    """Dotted module name -> (file, is a package's ``__init__``)."""
    out = {}
    for path in sorted(package.rglob("*.py")):
        parts = list(path.relative_to(package.parent).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        out[".".join(parts[:-1] if is_package else parts)] = (path, is_package)
    return out


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imported(tree: ast.Module, name: str, is_package: bool, modules: dict[str, tuple[Path, bool]]) -> set[str]:
    """The package's modules that ``tree`` (module ``name``) imports, anywhere but in
    ``if TYPE_CHECKING:`` blocks."""
    here = name if is_package else name.rpartition(".")[0]
    out: set[str] = set()

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child.test):
                for stmt in child.orelse:
                    visit_one(stmt)
            else:
                visit_one(child)

    def visit_one(node: ast.AST) -> None:
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name in modules)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = here.split(".")[: len(here.split(".")) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            for alias in node.names:
                if f"{source}.{alias.name}" in modules:
                    out.add(f"{source}.{alias.name}")
                elif source in modules:
                    out.add(source)
        visit(node)

    visit(tree)
    out.discard(name)
    return out


def python_graph(package: Path) -> Graph:
    modules = python_modules(package)
    return {name: _imported(ast.parse(path.read_text(encoding="utf-8"), str(path)), name, is_package, modules)
            for name, (path, is_package) in modules.items()}


# -- Rust -------------------------------------------------------------------------------------
_COMMENT_OR_STRING = re.compile(r'//[^\n]*|/\*.*?\*/|b?r#*"(?:.|\n)*?"#*|b?"(?:\\.|[^"\\])*"|\'(?:\\.|[^\'\\])\'', re.S)
_USE = re.compile(r"\buse\s+([^;]+);")
_PATH = re.compile(r"\b(?:crate|super|self)(?:\s*::\s*(?:super|\w+))+")
_INLINE_MOD = re.compile(r"\bmod\s+(\w+)\s*\{")
_DECLARED_MOD = re.compile(r"\bmod\s+(\w+)\s*;")


def rust_modules(src: Path) -> dict[tuple[str, ...], Path]:
    """Module path (segments below the crate root) -> file."""
    out: dict[tuple[str, ...], Path] = {}
    for path in sorted(src.rglob("*.rs")):
        parts = path.relative_to(src).with_suffix("").parts
        if parts in (("lib",), ("main",)):
            out[()] = path
        elif parts[-1] == "mod":
            out[parts[:-1]] = path
        else:
            out[parts] = path
    return out


def _strip(text: str) -> str:
    """Comments and string / char literals blanked (newlines kept)."""
    return _COMMENT_OR_STRING.sub(lambda m: re.sub(r"[^\n]", " ", m.group(0)), text)


def _use_paths(tree: str) -> list[str]:
    """A ``use`` tree expanded to plain paths: ``a::{b, c::{d, e}}`` -> a::b, a::c::d, a::c::e."""
    tree = re.sub(r"\s+", "", tree)
    if "{" not in tree:
        return [re.sub(r"::\*$|as\w+$", "", tree)]
    prefix, rest = tree.split("{", 1)
    body = rest[: rest.rfind("}")]
    items, depth, start = [], 0, 0
    for i, ch in enumerate(body):
        depth += {"{": 1, "}": -1}.get(ch, 0)
        if ch == "," and depth == 0:
            items.append(body[start:i])
            start = i + 1
    items.append(body[start:])
    return [p for item in items if item for p in _use_paths(prefix + item)]


def _inline_modules(code: str) -> list[tuple[int, int, str]]:
    """(start, end, name) of each inline ``mod name { ... }``."""
    out = []
    for m in _INLINE_MOD.finditer(code):
        depth, i = 1, m.end()
        while depth and i < len(code):
            depth += {"{": 1, "}": -1}.get(code[i], 0)
            i += 1
        out.append((m.start(), i, m.group(1)))
    return out


def _resolve(segments: list[str], module: tuple[str, ...], known: set[tuple[str, ...]]) -> tuple[str, ...] | None:
    """The longest known module that a path (``crate``/``super``/``self`` first) names."""
    if segments[0] == "crate":
        base, rest = (), segments[1:]
    else:
        base, rest = module, segments
        while rest and rest[0] in ("self", "super"):
            if rest[0] == "super":
                if not base:
                    return None
                base = base[:-1]
            rest = rest[1:]
    found = None
    for k in range(len(rest) + 1):
        candidate = base + tuple(rest[:k])
        if candidate in known:
            found = candidate
    return found


def rust_dependencies(path: Path, module: tuple[str, ...], known: set[tuple[str, ...]]) -> set[tuple[str, ...]]:
    code = _strip(path.read_text(encoding="utf-8"))
    inline = _inline_modules(code)
    children = {module + (name,) for name in _DECLARED_MOD.findall(code)} & known

    def scope(at: int) -> tuple[str, ...]:
        """The module path at offset ``at``: the file's, plus the inline modules around it."""
        return module + tuple(name for start, end, name in inline if start <= at < end)

    paths: list[tuple[int, list[str]]] = []
    for m in _USE.finditer(code):
        paths += [(m.start(), p.split("::")) for p in _use_paths(m.group(1))]
    for m in _PATH.finditer(code):
        paths.append((m.start(), re.sub(r"\s+", "", m.group(0)).split("::")))
    for child in children:  # `child::item` in code, not inside a longer path
        paths += [(m.start(), [child[-1]]) for m in re.finditer(rf"(?<![\w:]){child[-1]}\s*::", code)]
    out = set()
    for at, segments in paths:
        if segments[0] in ("crate", "super", "self"):
            target = _resolve(segments, scope(at), known)
        else:  # a relative path through a child module declared here
            target = _resolve(["self", *segments], module, known)
            target = target if target is not None and target[: len(module) + 1] in children else None
        if target is not None and target != module[: len(target)]:  # an ancestor (or itself): no edge
            out.add(target)
    return out


def rust_graph(src: Path) -> Graph:
    modules = rust_modules(src)
    known = set(modules)

    def name(m: tuple[str, ...]) -> str:
        return "::".join(("crate", *m))

    return {name(m): {name(t) for t in rust_dependencies(path, m, known)} for m, path in modules.items()}


# -- the checks -------------------------------------------------------------------------------
def test_python_package_has_no_import_circle() -> None:
    graph = python_graph(PACKAGE)
    assert len(graph) > 100 and sum(map(len, graph.values())) > 300  # the graph was read
    found = circles(graph)
    assert not found, f"import circles in python/insulator_rs: {_named(found)}"


@pytest.mark.parametrize("src", CRATE_SOURCES, ids=lambda p: str(p.relative_to(ROOT)))
def test_rust_crate_has_no_module_circle(src: Path) -> None:
    graph = rust_graph(src)
    assert graph and "crate" in graph
    found = circles(graph)
    assert not found, f"module circles in {src.relative_to(ROOT)}: {_named(found)}"


def test_rust_graph_reads_the_edges_it_must() -> None:
    """Known edges of fusion_core: a sibling by ``super::`` (sparse -> cells), by ``crate::`` in
    a brace tree (deskew -> culling, projection), a child by a relative path (dbscan -> grid)."""
    graph = rust_graph(ROOT / "crates" / "fusion_core" / "src")
    assert "crate::dbscan::cells" in graph["crate::dbscan::sparse"]
    assert {"crate::culling", "crate::projection"} <= graph["crate::deskew"]
    assert "crate::dbscan::grid" in graph["crate::dbscan"]
    assert "crate::dbscan" not in graph["crate::dbscan::sparse"]  # a child using its parent


def test_the_checks_see_a_circle(tmp_path: Path) -> None:
    """The same readers on small trees with a circle each: both name it."""
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from pkg.sub import b\n")
    (pkg / "sub" / "b.py").write_text("def f():\n    from .. import c\n")  # function-local: counts
    (pkg / "c.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg import d\n"
                              "from pkg import a\n")
    (pkg / "d.py").write_text("import pkg.c\n")  # c -> d only under TYPE_CHECKING: no circle
    assert circles(python_graph(pkg)) == [["pkg.a", "pkg.sub.b", "pkg.c", "pkg.a"]]

    src = tmp_path / "src"
    (src / "m").mkdir(parents=True)
    (src / "lib.rs").write_text("mod m;\nmod q;\n")
    (src / "m" / "mod.rs").write_text("mod x;\nmod y;\npub fn f() { x::f() } // use crate::q;\n")
    (src / "m" / "x.rs").write_text("use super::{y::{g, h}, *};\n")
    (src / "m" / "y.rs").write_text('const S: &str = "crate::q";\npub fn g() { crate::m::x::f() }\n'
                                    "#[cfg(test)]\nmod tests {\n    use super::super::*;\n}\n")
    (src / "q.rs").write_text("")
    assert circles(rust_graph(src)) == [["crate::m::x", "crate::m::y", "crate::m::x"]]
