"""Benchmark grids (task × algorithm × seed) and their reports.

    from d5rl.runner import expand_grid, run_bench, write_report
    cells = expand_grid(["a1-walk-v0"], ["bc", "iql"], seeds=[0, 1, 2], offline_steps=500_000, online_steps=0)
    run_bench(cells, "runs/a1")          # local processes; run_bench(..., ray_address="auto") on Ray
    write_report("runs/a1")              # runs/a1/report/report.md

The CLI front door is ``d5rl bench`` / ``d5rl report`` (:mod:`d5rl.runner.cli`).
"""

from d5rl.runner.bench import BenchResult, run_bench
from d5rl.runner.grid import Cell, expand_grid, find_cells
from d5rl.runner.report import write_report
from d5rl.runner.stats import iqm, stratified_bootstrap_ci

__all__ = [
    "BenchResult",
    "Cell",
    "expand_grid",
    "find_cells",
    "iqm",
    "run_bench",
    "stratified_bootstrap_ci",
    "write_report",
]
