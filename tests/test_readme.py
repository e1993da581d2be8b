"""The README's commands and code are the ones that work (docs cannot rot)."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

import d5rl
from tests.mdtables import agrees, doc_tables, entries

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
def test_result_tables_match_their_reports():
    """Each table of scores on the front page and the docs pages is the entries of the grid report it follows
    (the last ``docs/results/<grid>/`` linked above it), number for number: a hand-copied table cannot drift
    from ``d5rl report``'s output.  An entry may add a remark after the number (``(n=1)``).  Every published
    grid has a table checked this way, and the front page carries the headline one."""
    checked: dict[str, int] = {}
    for table in doc_tables(ROOT):
        name = table.page.relative_to(ROOT)
        assert table.grid, f"{name}: the table with columns {table.header} follows no link into docs/results/<grid>/"
        mine = entries(table.header, table.rows)
        assert mine, f"{name}: no (task, method) entries read from the table {table.header}"
        for key, cell in mine.items():
            assert key in table.reported, (
                f"{name} ({table.grid}): {key} is not in docs/results/{table.grid}/*_vs_paper.md"
            )
            assert agrees(cell, table.reported[key]), (
                f"{name} ({table.grid}) {key}: {cell!r}, its report says {table.reported[key]!r} "
                "(`python -m tests.mdtables` copies the reports' entries)"
            )
            checked[str(name)] = checked.get(str(name), 0) + 1
            checked[table.grid] = checked.get(table.grid, 0) + 1
    assert checked.get("README.md", 0) >= 50, f"only {checked.get('README.md', 0)} front-page entries were checked"
    published = {p.parent.name for p in (ROOT / "docs" / "results").glob("*/cells")}
    assert published and all(checked.get(g) for g in published), f"grids without a table: {published - set(checked)}"
