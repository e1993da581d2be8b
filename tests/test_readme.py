"""The README's commands and code are the ones that work (docs cannot rot)."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

import d5rl

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def code_blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", README, flags=re.S)


def test_exactly_two_setup_commands_and_ci_runs_the_test_one():
    setup = code_blocks("bash")[0]
    commands = [line.split("#")[0].strip() for line in setup.splitlines() if line.split("#")[0].strip()]
    assert commands == ["bash scripts/quickstart.sh", "bash scripts/test.sh"]
    ci = (ROOT / ".ci/run").read_text()
    assert re.search(r"^bash scripts/test\.sh\s*$", ci, flags=re.M)


def test_every_registered_task_is_in_the_task_table():
    for tid in d5rl.list_tasks():
        if tid.startswith("test-"):
            continue
        assert f"`{tid}`" in README, f"{tid} is missing from README's task table"


def test_cli_commands_in_readme_exist():
    from d5rl.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    for block in code_blocks("bash") + code_blocks("console"):
        for line in block.splitlines():
            m = re.match(r"\s*d5rl ([a-z0-9-]+)", line)
            if m:
                assert m.group(1) in sub.choices, f"README uses unknown command `d5rl {m.group(1)}`"


@pytest.mark.parametrize("index", range(len(code_blocks("python"))))
def test_python_blocks_run(index, tmp_path):
    code = code_blocks("python")[index]
    env_home = tmp_path / "home"
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600,
                          env={**__import__("os").environ, "D5RL_HOME": str(env_home), "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stderr[-3000:]


# --- published results: the README's result tables are copies of the reports' -------------------------------
def _tables(text: str) -> list[tuple[int, list[str], list[list[str]]]]:
    """Every markdown table of ``text``: (offset of its header line, header cells, body rows)."""
    out = []
    for m in re.finditer(r"^(\|.*\|)\n\|[-:| ]+\|\n((?:\|.*\|\n?)*)", text, flags=re.M):
        cells = lambda line: [c.strip() for c in line.strip().strip("|").split("|")]  # noqa: E731
        out.append((m.start(), cells(m.group(1)), [cells(r) for r in m.group(2).splitlines() if r.strip()]))
    return out


def _task_of(row: list[str]) -> str | None:
    for cell in row[:2]:
        m = re.search(r"[a-z0-9]+(?:-[a-z0-9]+)*-v\d+", cell)
        if m:
            return m.group(0)
    return None


def _entries(header, rows) -> dict[tuple[str, str], str]:
    """(task, method label) -> the table's entry, for the columns named after a method."""
    from d5rl.runner.report import METHODS

    labels = set(METHODS.values())
    out = {}
    for row in rows:
        task = _task_of(row)
        if task:
            out.update({(task, col): cell for col, cell in zip(header, row) if col in labels})
    return out


def test_readme_result_tables_match_their_reports():
    """Each README table of scores is the entries of the grid report it follows (the last
    ``docs/results/<grid>/`` named above it), number for number: a hand-copied table cannot drift from
    ``d5rl report``'s output.  A README entry may add a remark after the number (``(n=1)``)."""
    from d5rl.runner.report import METHODS

    checked = 0
    for start, header, rows in _tables(README):
        if not set(header) & set(METHODS.values()):
            continue
        grids = re.findall(r"docs/results/([\w-]+)/", README[:start])
        assert grids, f"the README's table with columns {header} follows no docs/results/<grid>/ link"
        report = ROOT / "docs/results" / grids[-1]
        ours = {}
        for path in sorted(report.glob("*_vs_paper.md")):
            for _, h, r in _tables(path.read_text()):
                ours.update(_entries(h, r))
        mine = _entries(header, rows)
        assert mine, f"no (task, method) entries read from the README's table {header}"
        for key, cell in mine.items():
            assert key in ours, f"README ({grids[-1]}): {key} is not in {report}/*_vs_paper.md"
            assert cell == ours[key] or cell.startswith(ours[key] + " "), \
                f"README ({grids[-1]}) {key}: {cell!r}, its report says {ours[key]!r}"
            checked += 1
    assert checked >= 50, f"only {checked} README entries were checked against reports"
