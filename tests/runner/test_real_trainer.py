"""The runner with d5rl's own training loop (JAX agents) on the numpy toy task."""

import json

import numpy as np
import pytest

pytest.importorskip("jax")

from d5rl.runner import expand_grid, run_bench, write_report
from d5rl.runner.grid import DEFAULT_JOB


@pytest.mark.slow
def test_bench_trains_real_agents(tmp_path):
    cells = expand_grid(
        ["toy-reach-v0"],
        ["bc", "iql"],
        [0],
        160,
        40,
        job=DEFAULT_JOB,
        protocol_overrides={"eval_interval": 80, "eval_episodes": 3},
    )
    result = run_bench(cells, tmp_path, workers=2, progress=False)
    assert not result.failed, (
        result.summary()
        + "\n"
        + "\n".join(
            (c.directory(tmp_path) / "error.txt").read_text()
            for c in cells
            if (c.directory(tmp_path) / "error.txt").exists()
        )
    )
    write_report(tmp_path, reps=100)
    import csv

    for name, phase_ok in (("table1_offline.csv", lambda s: s <= 160), ("table2_online.csv", lambda s: s > 160)):
        with open(tmp_path / "report" / name, newline="") as f:
            [row] = list(csv.DictReader(f))
        for cell in cells:
            cdir = cell.directory(tmp_path)
            resolved = json.loads((cdir / "config.json").read_text())
            assert resolved["train"]["eval_episodes"] == 3 and resolved["train"]["progress"] is False
            evals = [json.loads(line) for line in (cdir / "metrics.jsonl").read_text().splitlines()]
            evals = [r for r in evals if "eval/toy-reach-v0/score" in r and phase_ok(r["step"])]
            expected = evals[-1]["eval/toy-reach-v0/score"]
            assert float(row[f"{cell.algo}_mean"]) == pytest.approx(expected, abs=1e-12)
            assert np.isfinite(expected)
        summary = json.loads((cells[0].directory(tmp_path) / "done").read_text())["summary"]
        assert summary["step"] == 200 and "agent" not in summary
