"""Figures inline in README.md and docs/**/*.md, written from the committed results, never by hand.

A figure from a run is written between two HTML comments, which Markdown does not show:

    tactex takes <!-- fig tasks/clean_time/plate/X/ratio | .2f -->0.31<!-- /fig -->× the raster's time

The opening comment holds one or more keys (figure_sources: ``[FILE#]PATH``, default file
bench/results.json), then ``|`` and the steps that write them (figure_forms: ``%``, ``*1e3``,
``range``, ``min``, …, a format spec). ``make readme-status`` rewrites the text between the comments
from the sources; ``--check`` (and tests/test_readme_status.py) reports every figure whose text
differs, by file, line and key. A key that selects nothing writes "not measured".
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from figure_forms import FigureError, render
from figure_sources import Sources

# one line each: a figure is a word of a sentence, and a line number names it
MARKER = re.compile(r"<!-- fig (?P<spec>[^\n]*?) -->(?P<text>[^\n]*?)<!-- /fig -->")


@dataclass(frozen=True)
class Finding:
    """A figure whose text is not what its sources give, or a marker that cannot be rendered."""

    path: str
    line: int
    spec: str
    found: str
    expected: str | None  # None: the marker itself is wrong (``error`` says how)
    error: str = ""

    def __str__(self) -> str:
        if self.expected is None:
            return f"{self.path}:{self.line}: {self.spec}: {self.error}"
        return f"{self.path}:{self.line}: {self.spec}: reads {self.found!r}, the sources give {self.expected!r}"


def figure_text(spec: str, sources: Sources) -> str:
    """What the figure ``spec`` (the opening comment's content) writes from ``sources``."""
    keys_part, *steps = (part.strip() for part in spec.split("|"))
    keys = keys_part.split()
    if not keys:
        raise FigureError("no key before the first |")
    values: list | None = []
    for key in keys:
        found = sources.values(key)
        if found is None:  # a range or a ratio over the keys found would mislead: none is written
            values = None
            break
        values.extend(found)
    return render(values, [s for s in steps if s])


def rewrite(text: str, sources: Sources, path: str = "") -> tuple[str, list[Finding]]:
    """``text`` with every figure written from ``sources``, and what differed (a broken marker is left as
    it is and reported)."""
    findings: list[Finding] = []
    fences = _fenced_spans(text)

    def one(match: re.Match) -> str:
        spec, found = match["spec"], match["text"]
        line = text.count("\n", 0, match.start()) + 1
        if any(a <= match.start() < b for a, b in fences):
            findings.append(Finding(path, line, spec, found, None,
                                    "a marker inside a fenced code block is shown as it is written, comments and all: "
                                    "give the figure in the prose around the block"))
            return match[0]
        try:
            expected = figure_text(spec, sources)
        except FigureError as exc:
            findings.append(Finding(path, line, spec, found, None, str(exc)))
            return match[0]
        if expected != found:
            findings.append(Finding(path, line, spec, found, expected))
        return f"<!-- fig {spec} -->{expected}<!-- /fig -->"

    return MARKER.sub(one, text), findings


def _fenced_spans(text: str) -> list[tuple[int, int]]:
    """The character spans of ``text``'s fenced code blocks (between lines that start with three backticks)."""
    spans: list[tuple[int, int]] = []
    start, pos = None, 0
    for line in text.splitlines(keepends=True):
        if line.lstrip().startswith("```"):
            if start is None:
                start = pos
            else:
                spans.append((start, pos + len(line)))
                start = None
        pos += len(line)
    if start is not None:
        spans.append((start, len(text)))
    return spans


def doc_files(root: Path) -> list[Path]:
    """The pages whose figures are generated: README.md and every Markdown file under docs/."""
    return [p for p in [root / "README.md", *sorted((root / "docs").rglob("*.md"))] if p.is_file()]


def update(pages: list[Path], root: Path, sources: Sources, write: bool,
           texts: dict[Path, str] | None = None) -> list[Finding]:
    """Rewrite (``write``) or only compare the figures of ``pages``, named relative to ``root`` in the
    findings; ``texts`` gives a page's text instead of its file (the README with its status block
    already rewritten)."""
    findings: list[Finding] = []
    for page in pages:
        old = (texts or {}).get(page, page.read_text())
        name = str(page.relative_to(root)) if page.is_relative_to(root) else str(page)
        new, found = rewrite(old, sources, name)
        findings += found
        if write and new != page.read_text():
            page.write_text(new)
    return findings
