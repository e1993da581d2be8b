"""Markdown tables read back, to check the docs' and the browse page's numbers against ``d5rl report``'s."""

from __future__ import annotations

import re


def tables(text: str) -> list[tuple[int, list[str], list[list[str]]]]:
    """Every markdown table of ``text``: (offset of its header line, header cells, body rows)."""
    out = []
    for m in re.finditer(r"^(\|.*\|)\n\|[-:| ]+\|\n((?:\|.*\|\n?)*)", text, flags=re.M):
        cells = lambda line: [c.strip() for c in line.strip().strip("|").split("|")]  # noqa: E731
        out.append((m.start(), cells(m.group(1)), [cells(r) for r in m.group(2).splitlines() if r.strip()]))
    return out


def task_of(row: list[str]) -> str | None:
    """The task id a table row is about (in its first two cells), or None."""
    for cell in row[:2]:
        m = re.search(r"[a-z0-9]+(?:-[a-z0-9]+)*-v\d+", cell)
        if m:
            return m.group(0)
    return None


def entries(header, rows) -> dict[tuple[str, str], str]:
    """(task, method label) -> the table's entry, for the columns named after a method."""
    from d5rl.runner.results import METHODS

    labels = set(METHODS.values())
    out = {}
    for row in rows:
        task = task_of(row)
        if task:
            out.update({(task, col): cell for col, cell in zip(header, row) if col in labels})
    return out


def report_entries(text: str) -> dict[tuple[str, str], str]:
    """(task, method label) -> "ours / paper" from a report's comparison tables (``*_vs_paper.md`` or
    ``report.md``: the tables whose heading says "(ours / paper)")."""
    out = {}
    for start, header, rows in tables(text):
        heading = max(text.rfind("\n#", 0, start), 0)
        if "(ours / paper)" in text[heading:start].split("\n#")[-1]:
            out.update(entries(header, rows))
    return out
