"""Small, readable modules: no module of tactex/ over 800 lines and no function over 150, so that a
module holds one concept and a function one step of it (a longer one is split where its phases are)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent / "tactex"
MAX_MODULE_LINES = 800
MAX_FUNCTION_LINES = 150


def too_long(source: str, name: str) -> list[str]:
    """``name:line`` of every function of ``source`` over MAX_FUNCTION_LINES, and the module itself when it
    is over MAX_MODULE_LINES."""
    out = []
    lines = source.count("\n") + (not source.endswith("\n"))
    if lines > MAX_MODULE_LINES:
        out.append(f"{name}: {lines} lines (at most {MAX_MODULE_LINES})")
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            n = node.end_lineno - node.lineno + 1
            if n > MAX_FUNCTION_LINES:
                out.append(f"{name}:{node.lineno} {node.name}: {n} lines (at most {MAX_FUNCTION_LINES})")
    return out


def test_no_module_or_function_is_too_long() -> None:
    problems = [p for path in sorted(ROOT.rglob("*.py"))
                for p in too_long(path.read_text(encoding="utf-8"), str(path.relative_to(ROOT.parent)))]
    assert not problems, "split these by concept or phase:\n" + "\n".join(problems)


def test_the_check_finds_a_long_function_and_a_long_module() -> None:
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    assert too_long(f"def f():\n{body}\n", "m.py") == [f"m.py:1 f: {MAX_FUNCTION_LINES + 1} lines (at most 150)"]
    assert too_long("x = 1\n" * (MAX_MODULE_LINES + 1), "m.py") == ["m.py: 801 lines (at most 800)"]
    assert too_long("def f():\n    return 1\n", "m.py") == []
