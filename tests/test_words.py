"""Comments and docstrings in tactex/ say why, not which issue asked for it.

An issue number in a comment (``issue 21``, ``(#18)``) sends a reader to a tracker for the reason
instead of stating it; the reason belongs in the comment, the history in the commit message. This
scans every ``tactex/**/*.py``: comments through :mod:`tokenize`, docstrings (and other bare string
statements, e.g. attribute docstrings) through :mod:`ast`, and names each hit as ``file:line``.
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: An issue reference: "issue 21", "issues 21", "Issue #21", or "#18" standing alone (not an HTML
#: character reference such as "&#39;", not part of a word or a colour such as "#1f77b4").
ISSUE_REF = re.compile(r"\bissues?\s*#?\d+\b|(?<![\w&#])#\d+(?![\w.])", re.IGNORECASE)


def _comment_text(token: str) -> str:
    """A comment without its leading marker ('#', '#:' of attribute comments), so '# 3a' is not '#3'."""
    return re.sub(r"^#+:?", "", token)


def word_problems(source: str, name: str) -> list[str]:
    """Every issue reference in the comments and docstrings of ``source``, as ``name:line: text``."""
    found: list[tuple[int, str]] = []
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT and ISSUE_REF.search(_comment_text(tok.string)):
            found.append((tok.start[0], tok.string.strip()))
    for node in ast.walk(ast.parse(source)):
        if not (
            isinstance(node, ast.Expr)
            and isinstance(node.value, ast.Constant)
            and isinstance(node.value.value, str)
        ):
            continue
        # the raw text, so that each hit is named by the line it is on in the file
        segment = ast.get_source_segment(source, node.value) or ""
        for offset, line in enumerate(segment.splitlines()):
            if ISSUE_REF.search(line):
                found.append((node.value.lineno + offset, line.strip()))
    return [f"{name}:{line}: {text}" for line, text in sorted(found)]


def test_no_issue_numbers_in_comments_or_docstrings() -> None:
    files = sorted((ROOT / "tactex").rglob("*.py"))
    assert files, "no tactex/**/*.py found"
    problems: list[str] = []
    for path in files:
        rel = path.relative_to(ROOT).as_posix()
        problems += word_problems(path.read_text(encoding="utf-8"), rel)
    assert not problems, (
        "comments and docstrings should give the reason, not an issue number "
        "(the history goes to the commit message):\n" + "\n".join(problems)
    )


_SNIPPET = '''\
"""A module.

Handles the sparse case (issue 21).
"""

COLOUR = "#1f77b4"  # a colour is not an issue
ENTITY = "&#39;"


def f(x):
    """Clamp x, see (#18)."""
    # 3a: a phase label, not an issue
    label = "issue 5"  # a string value, not a comment
    return x  # Issue #7: the reason should be here


class C:
    size_m: float = 0.1
    """Side length [m]; issues 3 and 4 asked for it."""
'''


def test_word_problems_finds_issue_references_in_a_snippet() -> None:
    problems = word_problems(_SNIPPET, "snippet.py")
    assert [p.split(": ", 1)[0] for p in problems] == [
        "snippet.py:3",
        "snippet.py:11",
        "snippet.py:14",
        "snippet.py:19",
    ], problems


def test_word_problems_passes_a_clean_snippet() -> None:
    clean = '"""Clamp to the torque-rate limit: the robot stops on a faster change."""\n# phase 3a\nX = "#123"\n'
    assert word_problems(clean, "clean.py") == []
