"""The run directory: its file names are spelled in one module, and published run directories still read."""

import ast
from pathlib import Path

from d5rl.runner.grid import find_cells
from d5rl.runner.logs import read_evals
from d5rl.training import rundir
from d5rl.training.rundir import RunDir

REPO = Path(__file__).resolve().parents[2]
PACKAGE = REPO / "d5rl"
# The names of a run directory's files as published run directories (docs/results/**/cells) and older d5rl
# versions spell them, in the order of the RunDir attributes below
FILE_NAMES = [
    "config.json",
    "checkpoint",
    "checkpoint.prev",
    "metrics.jsonl",
    "metrics.csv",
    "eval_progress.json",
    "summary.json",
    ".train.lock",
    "cell.json",
    "failures.jsonl",
    "error.txt",
    "log.txt",
    ".worker.json",
    "done",
    "videos",
    "tb",
]
# What no module but rundir.py may spell: those names, but words too common to look for, and the names of
# the temporary checkpoint and of the evaluation logs older versions wrote
NAMES = {n for n in FILE_NAMES if n not in ("checkpoint", "done", "videos", "tb")}
NAMES |= {".checkpoint.tmp-", "bench.json", "eval.csv", "eval.jsonl"}


def test_the_names_are_those_run_directories_have():
    d = RunDir("/r")
    paths = [d.config, d.checkpoint, d.previous_checkpoint, d.metrics_jsonl, d.metrics_csv, d.eval_progress]
    paths += [d.summary, d.train_lock, d.cell, d.failures, d.error, d.log, d.worker, d.done, d.videos, d.tensorboard]
    assert [p.name for p in paths] == FILE_NAMES
    assert d.video(1200) == Path("/r/videos/step000001200.mp4") and d.checkpoint_tmp(7).name == ".checkpoint.tmp-7"
    assert rundir.EVAL_FILES == ("eval.csv", "eval.jsonl", "metrics.jsonl", "metrics.csv")
    assert rundir.BENCH_LOG == "bench.json" and rundir.CELL_LOCK == ".lock"


def _strings(tree: ast.AST):
    """Every string constant of a module but its docstrings (f-strings' literal parts included)."""
    docs = {
        id(n.body[0].value)
        for n in ast.walk(tree)
        if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
        and n.body
        and isinstance(n.body[0], ast.Expr)
        and isinstance(n.body[0].value, ast.Constant)
    }
    for n in ast.walk(tree):
        if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs:
            yield n


def test_no_module_but_rundir_spells_a_run_directory_file_name():
    """A string that is a run directory's file name, or a path ending in one, outside d5rl/training/rundir.py."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path == PACKAGE / "training" / "rundir.py":
            continue
        for node in _strings(ast.parse(path.read_text())):
            last = node.value.rstrip("/").rpartition("/")[2]
            if last in NAMES or any(node.value.endswith(f" {n}") for n in NAMES):
                found.append(f"{path.relative_to(REPO)}:{node.lineno}: {node.value!r}")
    assert found == []


def test_the_check_sees_a_name(tmp_path):
    tree = ast.parse('"""config.json in a docstring is fine."""\nx = "metrics.jsonl"\ny = f"{d}/summary.json"\n')
    strings = [n.value for n in _strings(tree)]
    assert strings == ["metrics.jsonl", "/summary.json"]


def test_a_published_grid_still_reads():
    """A cell of the published Table 1 (state) grid: its config, summary, done marker and evaluations."""
    [(cell, cdir), *_] = find_cells(REPO / "docs" / "results" / "table1-state" / "cells")
    d = RunDir(cdir)
    config = d.read_config()
    assert (config["algo"], config["task_id"], config["seed"]) == (cell.algo, cell.task, cell.seed)
    assert d.is_done() and d.read_summary()["step"] == cell.offline_steps + cell.online_steps
    assert d.eval_file() == d.metrics_jsonl and d.read_failures() == []
    evals = read_evals(cdir, cell.task, cell.offline_steps)
    assert evals and evals[-1]["step"] == cell.offline_steps
    assert evals[-1]["score"] == d.read_summary()["score"]
