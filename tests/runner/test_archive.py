"""What scripts/gpu_bench.sh brings back from a GPU machine: results always, then checkpoints in order."""

import pytest

pytest.importorskip("jax")

from d5rl.runner import expand_grid, run_bench
from d5rl.runner.archive import archive_files, main
from d5rl.runner.grid import DEFAULT_JOB
from d5rl.training.rundir import RunDir

PROTOCOL = {"eval_interval": 16, "eval_episodes": 2, "hidden_dims": "16,16", "batch_size": "16"}


def _size(paths, root):
    return sum((root / p).stat().st_size for p in paths)


def test_results_always_come_then_the_best_then_unfinished_checkpoints(tmp_path, capsys):
    root = tmp_path / "cells"  # scripts/gpu_bench.sh's layout: a folder of bench output directories
    run = root / "entry"
    cells = expand_grid(["toy-reach-v0"], ["bc"], [0, 1, 2], 16, 0, job=DEFAULT_JOB, overrides=PROTOCOL)
    assert not run_bench(cells, run, workers=0, progress=False).failed
    unfinished = cells[2].directory(run)
    RunDir(unfinished).done.unlink()  # as if the machine had stopped during its final evaluation
    for c in cells:
        (c.directory(run) / ".lock").write_text("")
        (c.directory(run) / "checkpoint.prev").mkdir()
        (c.directory(run) / "checkpoint.prev" / "x").write_text("old")

    files, kept = archive_files(root, 2**40)
    names = {str(p) for p in files}
    results = {p for p in names if "/checkpoint/" not in p}
    for c in cells:
        rel = c.directory(run).relative_to(root)
        assert f"{rel}/metrics.jsonl" in results and f"{rel}/cell.json" in results
    assert not [p for p in names if ".lock" in p or "checkpoint.prev" in p]
    best = next(c.directory(run) for c in cells if c.directory(run) in kept[:1])
    assert best != unfinished and kept == [best, unfinished]  # the best finished cell first, then unfinished

    only_results = [p for p in files if "/checkpoint/" not in str(p)]
    best_ckpt = [p for p in files if str(p).startswith(str(best.relative_to(root) / "checkpoint"))]
    budget = _size(only_results, root) + _size(best_ckpt, root)
    files, kept = archive_files(root, budget)  # room for one checkpoint: the best cell's
    assert kept == [best] and _size(files, root) <= budget
    files, kept = archive_files(root, 0)  # no room: the results still come, no checkpoint
    assert kept == [] and {str(p) for p in files} == results

    capsys.readouterr()
    assert main([str(root), "--budget-mib", "0"]) == 0
    assert set(capsys.readouterr().out.split()) == results
    assert main([str(root / "missing")]) == 2
