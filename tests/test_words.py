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
from fnmatch import fnmatch
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: Files being rewritten on other branches of the same renovation; their words are cleaned there.
#: The lead empties this list when those branches are merged: from then on every file is checked.
PENDING: tuple[str, ...] = (
    "tactex/commands/*",
    "tactex/config.py",
    "tactex/control/joint_kernels.py",
    "tactex/control/va_ufic.py",
    "tactex/control/va_ufic_compiled.py",
    "tactex/control/va_ufic_tick.py",
    "tactex/ergodic/*",
    "tactex/errors.py",
    "tactex/experiments/explore.py",
    "tactex/experiments/study*.py",
    "tactex/perception/realsense.py",
    "tactex/pointcloud/io.py",
    "tactex/pointcloud/mesh.py",
    "tactex/report/run_report.py",
    "tactex/robots/check.py",
    "tactex/sim/franka_sim_*.py",
    "tactex/sim/twin*.py",
    "tactex/spectral/eigen.py",
    "tactex/spectral/hierarchy.py",
    "tactex/tasks/clean.py",
    "tactex/tasks/demo.py",
    "tactex/tasks/runner.py",
)

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


def _is_pending(rel: str) -> bool:
    return any(fnmatch(rel, pattern) for pattern in PENDING)


def test_no_issue_numbers_in_comments_or_docstrings() -> None:
    files = sorted((ROOT / "tactex").rglob("*.py"))
    assert files, "no tactex/**/*.py found"
    problems: list[str] = []
    for path in files:
        rel = path.relative_to(ROOT).as_posix()
        if not _is_pending(rel):
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


def test_pending_is_only_for_other_branches() -> None:
    # a file outside PENDING is always checked: only the listed patterns are skipped
    assert _is_pending("tactex/ergodic/explorer.py")
    assert _is_pending("tactex/sim/twin_clock.py")
    assert not _is_pending("tactex/tasks/stroke.py")
    assert not _is_pending("tactex/cli.py")
