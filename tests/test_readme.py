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
