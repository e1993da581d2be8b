"""The README's commands and code are the ones that work (docs cannot rot)."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

import d5rl
from tests.mdtables import entries, report_entries, tables

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
    run_python(code_blocks("python")[index], tmp_path)


def run_python(code: str, tmp_path: Path) -> None:
    env_home = tmp_path / "home"
    proc = subprocess.run(
        [sys.executable, "-c", code],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
        env={**__import__("os").environ, "D5RL_HOME": str(env_home), "PYTHONPATH": str(ROOT)},
    )
    assert proc.returncode == 0, proc.stderr[-3000:]


# --- published results: the docs' result tables are copies of the reports' -----------------------------------
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]  # the front page and the docs pages
GRIDS = ROOT / "docs" / "results"
LINK = re.compile(r"\]\(([^)\s#]+)[^)]*\)")


def _grid_before(page: Path, text: str, start: int) -> str | None:
    """The grid (``docs/results/<grid>/``) of the last link above ``start`` that leads into one."""
    grid = None
    for target in LINK.findall(text[:start]):
        path = (page.parent / target).resolve()
        if path.is_relative_to(GRIDS) and path != GRIDS:
            grid = path.relative_to(GRIDS).parts[0]
    return grid


def test_result_tables_match_their_reports():
    """Each table of scores on the front page and the docs pages is the entries of the grid report it follows
    (the last ``docs/results/<grid>/`` linked above it), number for number: a hand-copied table cannot drift
    from ``d5rl report``'s output.  An entry may add a remark after the number (``(n=1)``).  Every published
    grid has a table checked this way, and the front page carries the headline one."""
    from d5rl.runner.results import METHODS

    checked: dict[str, int] = {}
    for page in PAGES:
        text = page.read_text()
        for start, header, rows in tables(text):
            if not set(header) & set(METHODS.values()):
                continue
            name = page.relative_to(ROOT)
            grid = _grid_before(page, text, start)
            assert grid, f"{name}: the table with columns {header} follows no link into docs/results/<grid>/"
            ours = {}
            for path in sorted((GRIDS / grid).glob("*_vs_paper.md")):
                ours.update(report_entries(path.read_text()))
            mine = entries(header, rows)
            assert mine, f"{name}: no (task, method) entries read from the table {header}"
            for key, cell in mine.items():
                assert key in ours, f"{name} ({grid}): {key} is not in docs/results/{grid}/*_vs_paper.md"
                assert cell == ours[key] or cell.startswith(ours[key] + " "), (
                    f"{name} ({grid}) {key}: {cell!r}, its report says {ours[key]!r}"
                )
                checked[str(name)] = checked.get(str(name), 0) + 1
                checked[grid] = checked.get(grid, 0) + 1
    assert checked.get("README.md", 0) >= 50, f"only {checked.get('README.md', 0)} front-page entries were checked"
    published = {p.parent.name for p in GRIDS.glob("*/cells")}
    assert published and all(checked.get(g) for g in published), f"grids without a table: {published - set(checked)}"
