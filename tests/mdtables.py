"""Markdown tables read back, to check the docs' and the browse page's numbers against ``d5rl report``'s, and
to copy a report's numbers into the docs' tables (``python -m tests.mdtables``, after ``d5rl report``)."""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TABLE = re.compile(r"^(\|.*\|)\n\|[-:| ]+\|\n((?:\|.*\|\n?)*)", flags=re.M)
LINK = re.compile(r"\]\(([^)\s#]+)[^)]*\)")


def tables(text: str) -> list[tuple[int, list[str], list[list[str]]]]:
    """Every markdown table of ``text``: (offset of its header line, header cells, body rows)."""
    out = []
    for m in TABLE.finditer(text):
        out.append((m.start(), _cells(m.group(1)), [_cells(r) for r in m.group(2).splitlines() if r.strip()]))
    return out


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


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


# --- the docs' result tables: copies of the grid reports' entries ------------------------------------------------
def pages(root: Path = ROOT) -> list[Path]:
    """The pages whose result tables are checked: the front page and the docs pages."""
    return [root / "README.md", *sorted((root / "docs").glob("*.md"))]


def grid_before(page: Path, text: str, start: int, grids: Path) -> str | None:
    """The grid (``<grids>/<grid>/``) of the last link above ``start`` that leads into one."""
    grid = None
    for target in LINK.findall(text[:start]):
        path = (page.parent / target).resolve()
        if path.is_relative_to(grids) and path != grids:
            grid = path.relative_to(grids).parts[0]
    return grid


@dataclass
class DocTable:
    """A table of scores on a docs page and the entries of the grid report it follows."""

    page: Path
    start: int
    header: list[str]
    rows: list[list[str]]
    grid: str | None
    reported: dict[tuple[str, str], str]  # (task, method label) -> the report's "ours / paper"


def doc_tables(root: Path = ROOT) -> list[DocTable]:
    """Every table of scores (a column named after a method) on ``pages(root)``, with its grid's report entries
    (``docs/results/<grid>/*_vs_paper.md``; the grid is the last one linked above the table)."""
    from d5rl.runner.results import METHODS

    grids = (root / "docs" / "results").resolve()
    reports: dict[str | None, dict[tuple[str, str], str]] = {None: {}}  # each grid's reports read once
    out = []
    for page in pages(root):
        text = page.read_text()
        for start, header, rows in tables(text):
            if not set(header) & set(METHODS.values()):
                continue
            grid = grid_before(page.resolve(), text, start, grids)
            if grid not in reports:
                reports[grid] = {}
                for path in sorted((grids / grid).glob("*_vs_paper.md")):
                    reports[grid].update(report_entries(path.read_text()))
            out.append(DocTable(page, start, header, rows, grid, reports[grid]))
    return out


def agrees(entry: str, reported: str) -> bool:
    """A docs entry agrees with its report's when it is the same, or the same followed by a remark."""
    return entry == reported or entry.startswith(reported + " ")


def sync(root: Path = ROOT, write: bool = True) -> list[str]:
    """Set every docs table entry that disagrees with its report to the report's (a remark after the old number
    goes with it: check the line printed). Returns one line per entry changed."""
    changes = []
    by_page: dict[Path, list[DocTable]] = {}
    for table in doc_tables(root):
        by_page.setdefault(table.page, []).append(table)
    for page, found in by_page.items():
        text = before = page.read_text()
        for table in sorted(found, key=lambda t: -t.start):  # from the end: earlier offsets stay valid
            m = TABLE.match(text, table.start)
            lines = m.group(0).split("\n")
            for i, line in enumerate(lines[2:], start=2):
                cells = _cells(line) if line.strip() else []
                task = task_of(cells)
                new = list(cells)
                for j, col in enumerate(table.header[: len(cells)]):
                    reported = table.reported.get((task, col))
                    if task and reported is not None and not agrees(cells[j], reported):
                        new[j] = reported
                        changes.append(f"{page.relative_to(root)}: {task} {col}: {cells[j]} -> {reported}")
                if new != cells:
                    lines[i] = "| " + " | ".join(new) + " |"
            text = text[: m.start()] + "\n".join(lines) + text[m.end() :]
        if write and text != before:
            page.write_text(text)
    return changes


if __name__ == "__main__":
    changed = sync(write="--check" not in sys.argv[1:])
    print("\n".join(changed) or "the docs' result tables agree with the reports")
    sys.exit(1 if changed and "--check" in sys.argv[1:] else 0)
