"""The package's floors: a module imports only from its own stage or an earlier one, and no two
modules import each other, directly or around a loop (DESIGN.md's stage table).

Every import counts, wherever it is written: at the top, inside a function, under
``if TYPE_CHECKING``, relative ones and ``import_module("tactex....")`` with a literal name. A
lazy import still says the importer needs the imported module, so it is held to the same order.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import pytest

PACKAGE = "tactex"
ROOT = Path(__file__).resolve().parents[1] / PACKAGE

# DESIGN.md's table: the first name under the package decides the stage.
STAGES: dict[str, int] = {
    "errors": 1,
    "config": 1,
    "geometry": 2,
    "pointcloud": 3,
    "perception": 4,
    "spectral": 4,
    "ergodic": 4,
    "control": 5,
    "sim": 6,
    "robots": 7,
    "twin": 8,
    "tasks": 9,
    "report": 10,
    "experiments": 11,
    "commands": 12,
    "cli": 12,
}
# The top-level package only re-exports the core types for users; inside the package nobody
# imports through it, so as an importer it is exempt and as an importee it counts as the top stage.
TOP_STAGE = max(STAGES.values())

# Cycles tolerated while a change that removes them is under way (none now). Each entry is the exact
# set of modules of one cycle; an entry that no longer matches a cycle fails the test too, so the list
# cannot outlive the cycles it excuses.
PENDING_CYCLES: frozenset[frozenset[str]] = frozenset()


@dataclass(frozen=True)
class Import:
    importer: str
    line: int
    imported: str


def collect_modules(root: Path, package: str) -> dict[str, Path]:
    """Dotted name → file of every module under ``root`` (a package ``a/b/__init__.py`` is ``a.b``)."""
    modules = {}
    for path in sorted(root.rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        modules[".".join([package, *parts])] = path
    return modules


def _resolve(target: str, names: list[str], modules: dict[str, Path]) -> list[str]:
    """The modules an import of ``names`` from ``target`` loads: a name that is a submodule is
    that module; any other name comes from ``target`` itself (or its nearest existing parent)."""
    found = []
    for name in names:
        sub = f"{target}.{name}" if name != "*" else ""
        if sub in modules:
            found.append(sub)
            continue
        parts = target.split(".")
        while parts and ".".join(parts) not in modules:
            parts.pop()
        if parts:
            found.append(".".join(parts))
    return found


def imports_of(name: str, path: Path, modules: dict[str, Path], package: str) -> list[Import]:
    """Every import of a module of ``package`` written anywhere in the file of module ``name``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_package = path.name == "__init__.py"
    result = []
    for node in ast.walk(tree):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            for alias in node.names:
                # A bare `import tactex` (for its folder or version) loads only what the top level
                # imports eagerly, the errors; its re-exports are reached by `from tactex import Name`.
                if alias.name.split(".")[0] == package and alias.name != package:
                    targets += _resolve(alias.name, [""], modules)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_package else name.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] == package:
                targets = _resolve(target, [alias.name for alias in node.names], modules)
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            func = node.func
            called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            literal = node.args[0].value
            if called == "import_module" and isinstance(literal, str) and literal.split(".")[0] == package:
                targets = _resolve(literal, [""], modules)
        result += [Import(name, node.lineno, t) for t in dict.fromkeys(targets) if t != name]
    return result


def all_imports(root: Path, package: str) -> list[Import]:
    modules = collect_modules(root, package)
    return [imp for name, path in modules.items() for imp in imports_of(name, path, modules, package)]


def stage_of(module: str, package: str, stages: dict[str, int]) -> int:
    parts = module.split(".")
    if len(parts) == 1:
        return max(stages.values())
    if parts[1] not in stages:
        raise KeyError(f"{module} is in no stage: add '{parts[1]}' to STAGES (DESIGN.md's table)")
    return stages[parts[1]]


def upward_imports(imports: list[Import], package: str, stages: dict[str, int]) -> list[str]:
    """One line per import of a later stage than the importer's (the top-level package exempt)."""
    found = []
    for imp in imports:
        if imp.importer == package:
            continue
        mine, theirs = stage_of(imp.importer, package, stages), stage_of(imp.imported, package, stages)
        if theirs > mine:
            found.append(f"{imp.importer} (stage {mine}) line {imp.line} imports {imp.imported} (stage {theirs})")
    return found


def import_cycles(edges: list[tuple[str, str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each as the shortest
    loop through its first module (repeated at the end) followed by the component's other
    modules, if any, after a ``+``; sorted for a stable message."""
    graph: dict[str, list[str]] = {}
    for a, b in edges:
        graph.setdefault(a, []).append(b)
        graph.setdefault(b, [])
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(v: str) -> None:  # recursion depth is bounded by the package's module count
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
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
                components.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    cycles = []
    for component in components:
        loop = _shortest_loop(graph, set(component))
        rest = [m for m in component if m not in loop]
        cycles.append(loop + (["+", *rest] if rest else []))
    return sorted(cycles)


def _shortest_loop(graph: dict[str, list[str]], component: set[str]) -> list[str]:
    """The shortest loop from the component's first module back to it, inside the component (BFS)."""
    start = min(component)
    previous: dict[str, str] = {}
    frontier = [start]
    while frontier:
        following = []
        for v in frontier:
            for w in sorted(graph[v]):
                if w == start:
                    path = [v]
                    while path[-1] != start:
                        path.append(previous[path[-1]])
                    return [*reversed(path), start]
                if w in component and w not in previous:
                    previous[w] = v
                    following.append(w)
        frontier = following
    raise AssertionError(f"{sorted(component)} is not strongly connected")  # pragma: no cover


def cycle_problems(imports: list[Import], pending: frozenset[frozenset[str]]) -> list[str]:
    """A line per cycle not in ``pending`` and per ``pending`` entry that is no longer a cycle."""
    cycles = import_cycles(sorted({(imp.importer, imp.imported) for imp in imports}))
    members = [frozenset(m for m in c if m != "+") for c in cycles]
    problems = [
        " → ".join(c).replace(" → + → ", " + ") for c, m in zip(cycles, members, strict=True) if m not in pending
    ]
    problems += [
        f"PENDING_CYCLES lists {sorted(p)}, which is no longer a cycle: remove the entry"
        for p in sorted(pending, key=sorted)
        if p not in members
    ]
    return problems


# --- the package -------------------------------------------------------------------------------


def test_every_import_goes_to_the_same_or_an_earlier_stage() -> None:
    upward = upward_imports(all_imports(ROOT, PACKAGE), PACKAGE, STAGES)
    assert not upward, "imports of a later stage (move the code down, or the import up):\n" + "\n".join(upward)


def test_no_import_cycles() -> None:
    problems = cycle_problems(all_imports(ROOT, PACKAGE), PENDING_CYCLES)
    assert not problems, "modules that import each other:\n" + "\n".join(problems)


def test_the_commands_call_experiments_not_the_report() -> None:
    """DESIGN.md: ``cli`` only parses and calls ``experiments``; the pages a command shows are the
    experiments' business, so a command never reaches into ``report`` itself."""
    front = (f"{PACKAGE}.commands", f"{PACKAGE}.cli")
    found = [f"{i.importer}:{i.line} imports {i.imported}" for i in all_imports(ROOT, PACKAGE)
             if i.importer.startswith(front) and i.imported.startswith(f"{PACKAGE}.report")]
    assert not found, "commands that import the report (call tactex.experiments instead):\n" + "\n".join(found)


def test_every_module_has_a_stage() -> None:
    for name in collect_modules(ROOT, PACKAGE):
        stage_of(name, PACKAGE, STAGES)


# --- the checker can fail ----------------------------------------------------------------------


def _package(tmp_path: Path, files: dict[str, str]) -> Path:
    root = tmp_path / "pkg"
    for rel, text in {"__init__.py": "", **files}.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


SYNTHETIC_STAGES = {"low": 1, "high": 2}


def test_checker_finds_every_kind_of_upward_import(tmp_path: Path) -> None:
    root = _package(
        tmp_path,
        {
            "low/__init__.py": "",
            "low/a.py": (
                "from typing import TYPE_CHECKING\n"
                "import pkg.high.top\n"  # line 2
                "if TYPE_CHECKING:\n"
                "    from pkg.high import typed\n"  # line 4
                "def f():\n"
                "    from ..high.lazy import thing\n"  # line 6: relative, inside a function
                "    import importlib\n"
                "    importlib.import_module('pkg.high.dynamic')\n"  # line 8
                "from pkg.low import b\n"  # same stage: fine
            ),
            "low/b.py": "",
            "high/__init__.py": "",
            "high/top.py": "from pkg.low import a\n",  # downward: fine (but a cycle with low/a)
            "high/typed.py": "",
            "high/lazy.py": "thing = 1\n",
            "high/dynamic.py": "",
        },
    )
    upward = upward_imports(all_imports(root, "pkg"), "pkg", SYNTHETIC_STAGES)
    assert upward == [
        f"pkg.low.a (stage 1) line {line} imports pkg.high.{mod} (stage 2)"
        for line, mod in [(2, "top"), (4, "typed"), (6, "lazy"), (8, "dynamic")]
    ]


def test_checker_resolves_names_and_relative_imports(tmp_path: Path) -> None:
    root = _package(
        tmp_path,
        {
            "low/__init__.py": "from .a import x\n",
            "low/a.py": "x = 1\n",
            "low/b.py": "from . import a\nfrom pkg.low import x\nimport pkg\n",
            "low/c.py": "from pkg import name\n",  # a re-export of the top level: the top stage
        },
    )
    imports = all_imports(root, "pkg")
    edges = {(i.importer, i.imported) for i in imports}
    assert edges == {
        ("pkg.low", "pkg.low.a"),
        ("pkg.low.b", "pkg.low.a"),
        ("pkg.low.b", "pkg.low"),
        ("pkg.low.c", "pkg"),
    }
    assert upward_imports(imports, "pkg", SYNTHETIC_STAGES) == ["pkg.low.c (stage 1) line 1 imports pkg (stage 2)"]


def test_checker_finds_and_names_a_cycle(tmp_path: Path) -> None:
    root = _package(
        tmp_path,
        {
            "low/__init__.py": "",
            "low/a.py": "from pkg.low.b import y\nx = 1\n",
            "low/b.py": "y = 2\ndef f():\n    from pkg.low import c\n",  # lazy, still a cycle
            "low/c.py": "from .a import x\n",
            "low/d.py": "from .a import x\n",  # not on the loop
        },
    )
    imports = all_imports(root, "pkg")
    assert cycle_problems(imports, frozenset()) == ["pkg.low.a → pkg.low.b → pkg.low.c → pkg.low.a"]
    assert cycle_problems(imports, frozenset({frozenset({"pkg.low.a", "pkg.low.b", "pkg.low.c"})})) == []


def test_a_pending_cycle_that_is_gone_is_reported() -> None:
    stale = frozenset({frozenset({"m.x", "m.y"})})
    assert cycle_problems([Import("m.x", 1, "m.y")], stale) == [
        "PENDING_CYCLES lists ['m.x', 'm.y'], which is no longer a cycle: remove the entry"
    ]


def test_cycles_from_edges_are_separate_components() -> None:
    edges = [("a", "b"), ("b", "a"), ("c", "d"), ("d", "e"), ("e", "c"), ("e", "f"), ("f", "f")]
    assert import_cycles(edges) == [["a", "b", "a"], ["c", "d", "e", "c"]]
    # two loops through "p": the shortest is named, the other module follows the "+"
    assert import_cycles([("p", "q"), ("q", "p"), ("p", "r"), ("r", "s"), ("s", "p")]) == [
        ["p", "q", "p", "+", "r", "s"]
    ]


def test_a_module_outside_the_table_is_named() -> None:
    with pytest.raises(KeyError, match="'annex'"):
        stage_of("tactex.annex.thing", PACKAGE, STAGES)
